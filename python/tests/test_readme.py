"""The README's Python example (and docs/python.md's) runs as written, and its result is what it says: the
smoothed and the filtered estimates of one call, a NaN row skipped; the filtered
ones equal filterpy's batch filter on the same model."""

import pathlib
import re

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
README = ROOT / "README.md"


def readme_example():
    text = README.read_text()
    section = text.split("## Python", 1)[1]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert blocks, "no python block in the README's Python section"
    return blocks[0]


def test_readme_example_runs_and_means_what_it_says():
    scope = {}
    exec(compile(readme_example(), "README.md", "exec"), scope)
    out = scope["out"]
    assert out.x.shape == (4, 2) and out.x_filtered.shape == (4, 2)
    assert np.isnan(out.nis[1]) and not np.isnan(out.nis[0])
    np.testing.assert_array_equal(out.x[-1], out.x_filtered[-1])
    assert np.max(np.abs(out.x[0] - out.x_filtered[0])) > 1e-3
    fp = pytest.importorskip("filterpy.kalman")
    kf = fp.KalmanFilter(2, 1)
    kf.F, kf.H, kf.Q, kf.R = scope["F"], scope["H"], scope["Q"], scope["R"]
    kf.x, kf.P = np.zeros(2), np.eye(2)
    means, _, _, _ = kf.batch_filter([None if np.isnan(z[0]) else z for z in scope["zs"]])
    np.testing.assert_allclose(out.x_filtered, means, rtol=1e-9, atol=1e-12)


def test_docs_python_md_examples_run():
    """docs/python.md's Python blocks run in order (the filterpy one included)."""
    text = (ROOT / "docs" / "python.md").read_text()
    scope = {}
    for block in re.findall(r"```python\n(.*?)```", text, flags=re.S):
        exec(compile(block, "docs/python.md", "exec"), scope)
    assert scope["report"].accepted
    assert scope["xs"].shape == (3, 2, 1)  # filterpy's column states
    assert "joint_min_eigenvalue=1.0" in repr(scope["report"])
    nav = scope["nav"]
    assert nav["status"] == "ok" and nav["dvl"]["accepted"] == 299
    assert abs(nav["latitude_deg"][-1] - 32.5) < 1e-6
