//! A fresh set of links: every receiver walks the whole source hierarchy.

use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use super::walk::{Walked, refine};
use super::{CHUNK, Chunk, LinkParams, Links, Oracle, assemble};
use crate::form_factors::{FfContext, FormFactorMethod};

/// Builds all links; `progress(done)` is called with the elements done so far.
pub fn build(
    ctx: &FfContext,
    method: &dyn FormFactorMethod,
    oracle: Oracle,
    params: &LinkParams,
    progress: &(dyn Fn(usize) + Sync),
) -> Links {
    let mesh = ctx.mesh;
    let n = mesh.element_count();
    let done = AtomicUsize::new(0);
    let chunks: Vec<Chunk> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let (lo, hi) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
            let mut chunk = Chunk::default();
            let mut stack = Vec::new();
            let mut row = Walked::default();
            let mut out = Vec::new();
            for leaf in lo..hi {
                row.clear();
                refine(
                    mesh,
                    leaf as u32,
                    &mesh.roots,
                    oracle,
                    params,
                    &mut stack,
                    &mut row,
                );
                out.clear();
                out.resize(row.src.len(), 0.0f32);
                method.compute(ctx, &row.as_row(leaf as u32), &mut out);
                chunk.push_row(row.src.iter().copied().zip(out.iter().copied()));
            }
            let d = done.fetch_add(hi - lo, Ordering::Relaxed) + (hi - lo);
            progress(d);
            chunk
        })
        .collect();
    assemble(n, chunks)
}
