//! The only module that touches tract: load an ONNX model once, fix its input facts
//! (a symbolic batch axis plus the metadata's per-input shape), optimise it, make it
//! runnable once, and run it many times (the tract pattern).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use tract_onnx::prelude::*;
use tract_onnx::tract_hir::infer::Factoid;

use crate::metadata::{InputMetadata, OutputMetadata};
use crate::{Error, Result};

/// A loaded, optimised, runnable ONNX model with `f32` inputs `[batch, shape...]` and one
/// `f32` output `[batch, size]`.
#[derive(Debug, Clone)]
pub(crate) struct OnnxModel {
    path: PathBuf,
    plan: Arc<TypedRunnableModel>,
    input_names: Vec<String>,
    input_shapes: Vec<Vec<usize>>,
    output_size: usize,
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
        let malformed = |e: TractError| Error::MalformedModel {
            path: path.to_path_buf(),
            reason: format!("{e:#}"),
        };
        let mut model = tract_onnx::onnx().model_for_path(path).map_err(malformed)?;

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
        let plan = typed
            .into_optimized()
            .and_then(|m| m.into_runnable())
            .map_err(malformed)?;
        Ok(OnnxModel {
            path: path.to_path_buf(),
            plan,
            input_names: inputs.iter().map(|m| m.name.clone()).collect(),
            input_shapes: inputs.iter().map(|m| m.shape.clone()).collect(),
            output_size: output.size,
        })
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
        let mut tensors: TVec<TValue> = TVec::new();
        for ((data, shape), name) in inputs.iter().zip(&self.input_shapes).zip(&self.input_names) {
            let mut dims = vec![batch];
            dims.extend_from_slice(shape);
            let want: usize = dims.iter().product();
            if data.len() != want {
                return Err(Error::InputMismatch {
                    expected: format!("{name}: {want} values ({dims:?})"),
                    given: format!("{name}: {} values", data.len()),
                });
            }
            let t =
                Tensor::from_shape(&dims, data).map_err(|e| Error::Inference(format!("{e:#}")))?;
            tensors.push(t.into_tvalue());
        }
        let out = self
            .plan
            .run(tensors)
            .map_err(|e| Error::Inference(format!("{}: {e:#}", self.path.display())))?;
        let first = out
            .first()
            .ok_or_else(|| Error::Inference("model produced no output".into()))?;
        let view = first
            .to_plain_array_view::<f32>()
            .map_err(|e| Error::Inference(format!("{e:#}")))?;
        if view.shape() != [batch, self.output_size] {
            return Err(Error::Inference(format!(
                "output shape {:?}, expected [{batch}, {}]",
                view.shape(),
                self.output_size
            )));
        }
        Ok(view.iter().copied().collect())
    }
}
