#!/usr/bin/env bash
# The long runs docs/results.md quotes, one log per run in results/:
# - estim-cli/src/study/tests/fuzz_parsers.rs, 1,000,000 cases, one property at a time (about 6-7 min in all);
# - estim-cli/src/study/tests/long_mission.rs, the 10-hour mission (ignored test; about 4 min) and the 1-hour one.
# - estim-cli/src/study/tests/square_root_ins.rs, the 10-hour mission in square-root form (ignored test).
# Each log's first line is the commit it ran on and the command. Run from the repository
# root on a clean work tree (the commit must be the code that ran), then
# `cargo run --release -- report --write docs/results.md` to quote the logs there.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -n "$(git status --porcelain --untracked-files=no)" ]; then
  echo "run_long.sh: the work tree has uncommitted changes; commit first" >&2
  exit 1
fi
commit="$(git rev-parse HEAD)"

run() { # run LOG COMMAND...
  local log="results/$1"; shift
  echo "$commit $*" > "$log"
  echo "== $*"
  # The command's own exit status is kept in the log ("test result:"); a failure stops here.
  env "$@" >> "$log" 2>&1
}

# The missions run beside the fuzzing (two processes for the machine's two cores).
(
  run long_mission-10h.log cargo test --release --bin estim study::tests::long_mission -- --ignored --nocapture
  run long_mission-1h.log cargo test --release --bin estim study::tests::long_mission -- --nocapture
  run long_mission-10h-square-root.log cargo test --release --bin estim study::tests::square_root_ins -- --ignored --nocapture
) &
missions=$!

cases="${ESTIM_FUZZ_CASES:-1000000}"
properties=$(cargo test --release --bin estim study::tests::fuzz_parsers -- --list 2>/dev/null \
  | sed -n 's/^\(.*survives_.*\): test$/\1/p')
for p in $properties; do
  run "fuzz_parsers-${p##*::}.log" ESTIM_FUZZ_CASES="$cases" cargo test --release --bin estim study::tests::fuzz_parsers -- --exact "$p"
done
wait "$missions"
