//! Accuracy metrics of the BeamsNet paper, computed on the velocity norm |v|.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// RMSE, MAE, R^2 and VAF of one prediction series.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// Root-mean-square error \[m/s\].
    pub rmse: f64,
    /// Mean absolute error \[m/s\].
    pub mae: f64,
    /// Coefficient of determination.
    pub r2: f64,
    /// Variance accounted for \[%\].
    pub vaf: f64,
}

/// Metrics of scalar predictions against a reference series.
///
/// With y the reference speeds, ŷ the predictions and e = y - ŷ (n samples):
/// - RMSE = sqrt(mean(e^2)), MAE = mean(|e|),
/// - R^2 = 1 - sum(e^2) / sum((y - mean(y))^2) (coefficient of determination),
/// - VAF = 100 (1 - var(e) / var(y)) \[%\] (variance accounted for; a constant offset
///   in e does not lower it, which is why the paper's LS VAF exceeds its R^2).
pub fn metrics(reference: &[f64], predicted: &[f64]) -> Result<Metrics> {
    if reference.len() != predicted.len() {
        return Err(Error::Metrics(format!(
            "{} reference values but {} predictions",
            reference.len(),
            predicted.len()
        )));
    }
    if reference.len() < 2 {
        return Err(Error::Metrics("need at least 2 samples".into()));
    }
    if reference.iter().chain(predicted).any(|v| !v.is_finite()) {
        return Err(Error::Metrics("non-finite value in the series".into()));
    }
    let n = reference.len() as f64;
    let errors: Vec<f64> = reference
        .iter()
        .zip(predicted)
        .map(|(y, p)| y - p)
        .collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / n;
    let variance = |v: &[f64]| {
        let m = mean(v);
        v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n
    };
    let sse: f64 = errors.iter().map(|e| e * e).sum();
    let var_y = variance(reference);
    if var_y <= 0.0 {
        return Err(Error::Metrics(
            "reference has zero variance: R^2 and VAF undefined".into(),
        ));
    }
    Ok(Metrics {
        rmse: (sse / n).sqrt(),
        mae: errors.iter().map(|e| e.abs()).sum::<f64>() / n,
        r2: 1.0 - sse / (var_y * n),
        vaf: 100.0 * (1.0 - variance(&errors) / var_y),
    })
}

/// Metrics on the velocity norm |v| (the paper's convention).
pub fn speed_metrics(reference: &[Vector3<f64>], predicted: &[Vector3<f64>]) -> Result<Metrics> {
    let r: Vec<f64> = reference.iter().map(|v| v.norm()).collect();
    let p: Vec<f64> = predicted.iter().map(|v| v.norm()).collect();
    metrics(&r, &p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn hand_computed_values() {
        // y = [1, 2, 3, 4], p = [1.1, 1.9, 3.2, 4.0]: e = [-0.1, 0.1, -0.2, 0]
        // sum e^2 = 0.06 -> RMSE = sqrt(0.015); MAE = 0.4 / 4 = 0.1
        // var(y) = 1.25 (population), sum (y - 2.5)^2 = 5 -> R^2 = 1 - 0.06 / 5 = 0.988
        // mean e = -0.05, var e = (0.0025 + 0.0225 + 0.0225 + 0.0025) / 4 = 0.0125
        // VAF = 100 (1 - 0.0125 / 1.25) = 99
        let m = metrics(&[1.0, 2.0, 3.0, 4.0], &[1.1, 1.9, 3.2, 4.0]).unwrap();
        assert_relative_eq!(m.rmse, 0.015f64.sqrt(), epsilon = 1e-12);
        assert_relative_eq!(m.mae, 0.1, epsilon = 1e-12);
        assert_relative_eq!(m.r2, 0.988, epsilon = 1e-12);
        assert_relative_eq!(m.vaf, 99.0, epsilon = 1e-10);
    }

    #[test]
    fn constant_offset_lowers_r2_not_vaf() {
        let y = [1.0, 2.0, 3.0];
        let p = [1.5, 2.5, 3.5];
        let m = metrics(&y, &p).unwrap();
        assert_relative_eq!(m.vaf, 100.0, epsilon = 1e-12);
        // sum e^2 = 0.75, sum (y - 2)^2 = 2 -> R^2 = 0.625
        assert_relative_eq!(m.r2, 0.625, epsilon = 1e-12);
        assert_relative_eq!(m.rmse, 0.5, epsilon = 1e-12);
    }

    #[test]
    fn speed_uses_the_norm() {
        let r = [Vector3::new(3.0, 4.0, 0.0), Vector3::new(0.0, 0.0, 1.0)];
        let p = [Vector3::new(0.0, 5.0, 0.0), Vector3::new(0.0, 1.0, 0.0)];
        let m = speed_metrics(&r, &p).unwrap();
        assert_eq!(m.rmse, 0.0);
    }

    #[test]
    fn bad_series_are_errors() {
        assert!(metrics(&[1.0, 2.0], &[1.0]).is_err());
        assert!(metrics(&[1.0], &[1.0]).is_err());
        assert!(metrics(&[1.0, 1.0], &[1.0, 2.0]).is_err());
        assert!(metrics(&[1.0, f64::NAN], &[1.0, 2.0]).is_err());
    }
}
