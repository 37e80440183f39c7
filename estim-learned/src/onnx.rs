//! The only module that touches tract: load an ONNX model once, fix its input facts
//! (a symbolic batch axis plus the metadata's per-input shape), then, per batch size
//! run, fix the batch axis, optimise, make it runnable once, and run it many times (the
//! tract pattern).

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use tract_onnx::prelude::*;
use tract_onnx::tract_hir::infer::Factoid;

use crate::metadata::{InputMetadata, OutputMetadata};
use crate::{Error, Result};

/// A loaded ONNX model with `f32` inputs `[batch, shape...]` and one `f32` output
/// `[batch, size]`, run through plans optimised for each batch size it is run with.
#[derive(Debug)]
pub(crate) struct OnnxModel {
    path: PathBuf,
    /// The typed model with a symbolic batch axis, from which the plans are made.
    typed: Arc<TypedModel>,
    batch: Symbol,
    /// Plans made for concrete batch sizes, most recently used first; shared by the
    /// clones of this model and by the threads running it.
    plans: Arc<Mutex<Vec<PlanForBatch>>>,
    input_names: Vec<String>,
    input_shapes: Vec<Vec<usize>>,
    output_size: usize,
    /// What [`OnnxModel::run_with`] reuses from one call to the next, so that a
    /// repeated call copies nothing and allocates nothing of its own.
    scratch: Mutex<Scratch>,
}

impl Clone for OnnxModel {
    /// The plans are shared; the clone gets its own (empty) scratch.
    fn clone(&self) -> Self {
        Self {
            path: self.path.clone(),
            typed: Arc::clone(&self.typed),
            batch: self.batch.clone(),
            plans: Arc::clone(&self.plans),
            input_names: self.input_names.clone(),
            input_shapes: self.input_shapes.clone(),
            output_size: self.output_size,
            scratch: Mutex::new(Scratch::default()),
        }
    }
}

/// A batch size and the plan made for it.
type PlanForBatch = (usize, Arc<TypedRunnableModel>);

/// Batch sizes whose tract state and input tensors are kept (e.g. 1 for a
/// measurement, 1 + N for a sensitivity batch); the least recently used set is
/// replaced beyond this.
const KEPT_BATCH_SIZES: usize = 4;

/// Batch sizes whose optimised plan is kept (a plan costs 10-35 ms to make for
/// BeamsNet, against about 50 µs per inference).
const KEPT_PLANS: usize = 8;

/// Per batch size: the spawned tract state of that size's plan and one input tensor
/// per model input. A tensor is handed to tract as a shared reference
/// (`TValue::from_const`); once tract has dropped its reference after the run, the
/// next call refills it in place.
#[derive(Debug, Default)]
struct Scratch {
    batches: Vec<BatchScratch>,
}

#[derive(Debug)]
struct BatchScratch {
    batch: usize,
    state: TypedSimpleState,
    inputs: Vec<Arc<Tensor>>,
}

fn describe(name: &str, shape: &[usize]) -> String {
    let dims: Vec<String> = std::iter::once("batch".to_string())
        .chain(shape.iter().map(|d| d.to_string()))
        .collect();
    format!("{name}: f32 [{}]", dims.join(", "))
}

impl OnnxModel {
    /// Load `path` and check it against the declared inputs and output.
    pub(crate) fn load(
        path: &Path,
        inputs: &[InputMetadata],
        output: &OutputMetadata,
    ) -> Result<Self> {
        if !path.is_file() {
            return Err(Error::MissingFile {
                path: path.to_path_buf(),
                what: "ONNX model",
            });
        }
        let model = tract_onnx::onnx()
            .model_for_path(path)
            .map_err(|e| Error::MalformedModel {
                path: path.to_path_buf(),
                reason: format!("{e:#}"),
            })?;
        Self::from_inference_model(model, path, inputs, output)
    }

    /// [`Self::load`] from the bytes of an ONNX file; `path` names them in errors.
    pub(crate) fn load_bytes(
        bytes: &[u8],
        path: &Path,
        inputs: &[InputMetadata],
        output: &OutputMetadata,
    ) -> Result<Self> {
        let model = tract_onnx::onnx()
            .model_for_read(&mut std::io::Cursor::new(bytes))
            .map_err(|e| Error::MalformedModel {
                path: path.to_path_buf(),
                reason: format!("{e:#}"),
            })?;
        Self::from_inference_model(model, path, inputs, output)
    }

    fn from_inference_model(
        mut model: InferenceModel,
        path: &Path,
        inputs: &[InputMetadata],
        output: &OutputMetadata,
    ) -> Result<Self> {
        let malformed = |e: TractError| Error::MalformedModel {
            path: path.to_path_buf(),
            reason: format!("{e:#}"),
        };

        // Inputs: names and count must match, declared dtype/rank/fixed dims too.
        let outlets = model.input_outlets().map_err(malformed)?.to_vec();
        let mut declared = Vec::with_capacity(outlets.len());
        for (i, outlet) in outlets.iter().enumerate() {
            let fact = model.input_fact(i).map_err(malformed)?;
            declared.push(format!(
                "{}: {}",
                model.node(outlet.node).name,
                fact.format_dt_shape()
            ));
        }
        let given: Vec<String> = inputs.iter().map(|m| describe(&m.name, &m.shape)).collect();
        let mismatch = || Error::ModelMetadataMismatch {
            path: path.to_path_buf(),
            expected: format!("inputs [{}]", declared.join("; ")),
            given: format!("inputs [{}]", given.join("; ")),
        };
        if outlets.len() != inputs.len() {
            return Err(mismatch());
        }
        for (i, (outlet, meta)) in outlets.iter().zip(inputs).enumerate() {
            if model.node(outlet.node).name != meta.name {
                return Err(mismatch());
            }
            let fact = model.input_fact(i).map_err(malformed)?;
            if let Some(dt) = fact.datum_type.concretize() {
                if dt != f32::datum_type() {
                    return Err(mismatch());
                }
            }
            if let Some(rank) = fact.shape.rank().concretize() {
                if rank != meta.shape.len() as i64 + 1 {
                    return Err(mismatch());
                }
                for (dim, want) in fact.shape.dims().skip(1).zip(&meta.shape) {
                    if let Some(d) = dim.concretize().and_then(|d| d.to_i64().ok()) {
                        if d != *want as i64 {
                            return Err(mismatch());
                        }
                    }
                }
            }
        }
        let out_outlets = model.output_outlets().map_err(malformed)?.to_vec();
        let out_names: Vec<String> = out_outlets
            .iter()
            .map(|o| {
                model
                    .outlet_label(*o)
                    .map_or_else(|| model.node(o.node).name.clone(), str::to_string)
            })
            .collect();
        if out_names.len() != 1 || out_names[0] != output.name {
            return Err(Error::ModelMetadataMismatch {
                path: path.to_path_buf(),
                expected: format!("outputs [{}]", out_names.join(", ")),
                given: format!("output {} of size {}", output.name, output.size),
            });
        }

        // Fix the input facts: symbolic batch, metadata shape.
        let batch = model.symbols.sym("batch");
        for (i, meta) in inputs.iter().enumerate() {
            let dims: Vec<TDim> = std::iter::once(TDim::Sym(batch.clone()))
                .chain(meta.shape.iter().map(|&d| TDim::from(d as i64)))
                .collect();
            model = model
                .with_input_fact(i, f32::fact(dims).into())
                .map_err(malformed)?;
        }
        let typed = model.into_typed().map_err(malformed)?;
        let out_fact = typed.output_fact(0).map_err(malformed)?;
        let out_dims: Vec<TDim> = out_fact.shape.iter().cloned().collect();
        let size_ok = out_dims.len() == 2 && out_dims[1].to_i64().ok() == Some(output.size as i64);
        if out_fact.datum_type != f32::datum_type() || !size_ok {
            return Err(Error::ModelMetadataMismatch {
                path: path.to_path_buf(),
                expected: format!("output {}: {:?}", output.name, out_fact),
                given: format!("output {}: f32 [batch, {}]", output.name, output.size),
            });
        }
        let typed = typed.into_decluttered().map_err(malformed)?;
        let model = OnnxModel {
            path: path.to_path_buf(),
            typed: Arc::new(typed),
            batch,
            plans: Arc::new(Mutex::new(Vec::new())),
            input_names: inputs.iter().map(|m| m.name.clone()).collect(),
            input_shapes: inputs.iter().map(|m| m.shape.clone()).collect(),
            output_size: output.size,
            scratch: Mutex::new(Scratch::default()),
        };
        // The plan of a single measurement, made now: a model that tract cannot
        // optimise is refused at load, and the first measurement does not wait.
        model.plan_for(1).map_err(malformed)?;
        Ok(model)
    }

    /// The plan for `batch`: made once per batch size (the batch axis fixed, then
    /// optimised) and kept. A plan for a concrete size runs faster and allocates less
    /// per run than one plan with a symbolic batch axis (BeamsNet, batch 1: 85 heap
    /// allocations per run instead of 127; estim-learned/README.md).
    fn plan_for(&self, batch: usize) -> TractResult<Arc<TypedRunnableModel>> {
        let mut plans = self.plans.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = plans.iter().position(|(b, _)| *b == batch) {
            plans[..=i].rotate_right(1);
            return Ok(Arc::clone(&plans[0].1));
        }
        let size = i64::try_from(batch)?;
        let mut values = std::collections::HashMap::new();
        values.insert(self.batch.clone(), TDim::Val(size));
        let plan = self
            .typed
            .set_symbols(&values)?
            .into_optimized()?
            .into_runnable()?;
        if plans.len() == KEPT_PLANS {
            plans.pop();
        }
        plans.insert(0, (batch, Arc::clone(&plan)));
        Ok(plan)
    }

    /// The state and input tensors for `batch` in `scratch`, most recently used first.
    fn batch_scratch<'s>(
        &self,
        scratch: &'s mut Scratch,
        batch: usize,
    ) -> TractResult<&'s mut BatchScratch> {
        match scratch.batches.iter().position(|b| b.batch == batch) {
            Some(i) => scratch.batches[..=i].rotate_right(1),
            None => {
                let state = self.plan_for(batch)?.spawn()?;
                let inputs = self
                    .input_shapes
                    .iter()
                    .map(|shape| {
                        let mut dims = Vec::with_capacity(shape.len() + 1);
                        dims.push(batch);
                        dims.extend_from_slice(shape);
                        Tensor::zero::<f32>(&dims).map(Arc::new)
                    })
                    .collect::<TractResult<Vec<_>>>()?;
                if scratch.batches.len() == KEPT_BATCH_SIZES {
                    scratch.batches.pop();
                }
                scratch.batches.insert(
                    0,
                    BatchScratch {
                        batch,
                        state,
                        inputs,
                    },
                );
            }
        }
        Ok(&mut scratch.batches[0])
    }

    /// Run one batch, writing the inputs in place and reading the output in place.
    ///
    /// `fill(k, values)` writes input k: `values` holds `batch * prod(shape_k)` values
    /// in row-major order (batch first). `read(values)` receives the `batch *
    /// output_size` output values. The plan of this batch size, its tract state and
    /// the input tensors are kept from one call to the next (see [`Scratch`]); when
    /// another thread holds the scratch, this call spawns a fresh state of the shared
    /// plan instead of waiting.
    pub(crate) fn run_with(
        &self,
        batch: usize,
        mut fill: impl FnMut(usize, &mut [f32]) -> Result<()>,
        read: impl FnOnce(&[f32]) -> Result<()>,
    ) -> Result<()> {
        if batch == 0 {
            return Err(Error::InputMismatch {
                expected: "batch >= 1".into(),
                given: "batch 0".into(),
            });
        }
        let inference = |e: TractError| Error::Inference(format!("{}: {e:#}", self.path.display()));
        let mut local;
        let mut guard = self.scratch.try_lock();
        let scratch: &mut Scratch = match guard.as_deref_mut() {
            Ok(s) => s,
            Err(_) => {
                local = Scratch::default();
                &mut local
            }
        };
        let entry = self.batch_scratch(scratch, batch).map_err(inference)?;
        let mut values: TVec<TValue> = TVec::new();
        for (k, tensor) in entry.inputs.iter_mut().enumerate() {
            // Unique after the previous run (tract dropped its reference); if not,
            // make_mut copies it once and the copy is kept.
            let mut view = Arc::make_mut(tensor)
                .try_as_plain_ram_mut()
                .map_err(inference)?;
            fill(k, view.as_slice_mut::<f32>().map_err(inference)?)?;
            values.push(TValue::from_const(Arc::clone(tensor)));
        }
        let out = entry.state.run(values).map_err(inference)?;
        let first = out
            .first()
            .ok_or_else(|| Error::Inference("model produced no output".into()))?;
        if first.shape() != [batch, self.output_size] {
            return Err(Error::Inference(format!(
                "output shape {:?}, expected [{batch}, {}]",
                first.shape(),
                self.output_size
            )));
        }
        let view = first.try_as_plain_ram().map_err(inference)?;
        read(view.as_slice::<f32>().map_err(inference)?)
    }

    /// Run one batch. `inputs[k]` holds `batch * prod(shape_k)` values in row-major
    /// order; returns `batch * output_size` values.
    pub(crate) fn run(&self, batch: usize, inputs: &[Vec<f32>]) -> Result<Vec<f32>> {
        if batch == 0 || inputs.len() != self.input_shapes.len() {
            return Err(Error::InputMismatch {
                expected: format!(
                    "{} tensors ({}) with batch >= 1",
                    self.input_shapes.len(),
                    self.input_names.join(", ")
                ),
                given: format!("{} tensors with batch {batch}", inputs.len()),
            });
        }
        for ((data, shape), name) in inputs.iter().zip(&self.input_shapes).zip(&self.input_names) {
            let want = batch * shape.iter().product::<usize>();
            if data.len() != want {
                return Err(Error::InputMismatch {
                    expected: format!("{name}: {want} values ([{batch}, {shape:?}])"),
                    given: format!("{name}: {} values", data.len()),
                });
            }
        }
        let mut out = Vec::new();
        self.run_with(
            batch,
            |k, values| {
                values.copy_from_slice(&inputs[k]);
                Ok(())
            },
            |values| {
                out.extend_from_slice(values);
                Ok(())
            },
        )?;
        Ok(out)
    }
}
