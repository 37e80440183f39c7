//! The linear-algebra layer of estim-core, one layer below the filters: every
//! product, factorisation and CPU dispatch the algorithm files use is here, and
//! each is documented the way nalgebra documents its decompositions (what it
//! computes, pivot rule, tolerance, failure).
//!
//! | module | what |
//! |---|---|
//! | [`static_products`] | A B, A B', A L (lower L) as inlined loops |
//! | [`fused_product`] | the dense products of 8+ states by an AVX-512F fused loop, else the loops |
//! | [`inverse`] | S^-1 of a small SPD matrix (closed forms for 1 and 2 rows, Cholesky) |
//! | [`cholesky`] | the one semidefinite Cholesky (pivot tolerance 16 n eps) and the joint factor |
//! | [`givens`] | Givens triangularisation of the square-root pre-arrays |
//! | [`ldl`] | the LDL' certificate of a correlation matrix (tolerance sqrt(eps)) |
//! | [`dispatch`] | which hand-tuned build runs; `ESTIM_FORCE_PORTABLE=1` forces the portable one |
//!
//! Hand-tuned builds (AVX2 linear runner, AVX-512F fused product, AVX-512F joint
//! factor) are chosen only through [`dispatch`], and each has a test that compares
//! it with the portable path in the same process.

pub(crate) mod cholesky;
pub mod dispatch;
pub(crate) mod fused_product;
pub(crate) mod givens;
pub(crate) mod inverse;
pub(crate) mod ldl;
pub(crate) mod static_products;

#[cfg(test)]
pub(crate) use cholesky::joint_factor_general;
pub(crate) use cholesky::{
    joint_factor, joint_factor_from, joint_factor_into, semidefinite_cholesky, Blocks,
};
pub(crate) use fused_product::{
    gram_pair_into, minus_product_into, product, product_into, product_transposed,
    product_transposed_into,
};
pub(crate) use givens::lower_triangularize_pair;
pub(crate) use inverse::{positive_normal, spd_inverse, spd_inverse_log_det};
#[cfg(test)]
pub(crate) use ldl::certify_psd_with;
pub(crate) use ldl::{certify_block, certify_psd};
pub(crate) use static_products::{mul_lower_into, mul_static, mul_transpose_static};
