//! Links: which source nodes each element gathers from, and their form factors.
//!
//! Each receiver element, sampled at its centroid, walks the source hierarchy top-down (the
//! source side of Hanrahan, Salzman & Aupperle 1991): a source node is split into its four
//! children while its estimated transport `F × B̂` exceeds `refinement × B_ambient`, otherwise it
//! becomes a link. `F` is the exact unoccluded point-to-polygon value, so the links of a receiver
//! tile everything it sees and, unoccluded, sum to exactly 1 in a closed scene (the furnace
//! holds). The chosen [`crate::FormFactorKind`] then computes each link's value, occlusion included.
//!
//! With `hierarchical = false` every element links to every patch it sees (Cohen et al.'s
//! patch–element substructuring): the classic O(elements × patches) baseline.

//!
//! One file per operation: [`build`] (a fresh set of links), [`update`] (after a geometry
//! edit), the refinement walk both share (`walk`), and the shaft tests an update culls with
//! ([`shaft`]).

mod build;
pub mod shaft;
mod update;
mod walk;

pub use build::build;
pub use shaft::{ChangeSet, Pyramid, SeenFrom, shaft_hits_box};
pub use update::{Change, Scratch, UpdateStats, update};

/// Refinement parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkParams {
    /// Below the patch level, split a source while `F × B̂ > refinement × B_ambient`, with `B̂`
    /// its estimated radiosity (default: 0.02). Smaller is more accurate and slower.
    pub refinement: f64,
    /// Adaptive source hierarchy (true) or every element to every patch (false).
    pub hierarchical: bool,
    /// Above the patch level, split unless `F × B̂` is below `far_field × refinement ×
    /// B_ambient` (default: 0.05).
    pub far_field: f64,
    /// Most visibility samples on one link (default: 16).
    pub max_samples: u8,
}

impl Default for LinkParams {
    fn default() -> Self {
        LinkParams {
            refinement: 0.02,
            hierarchical: true,
            far_field: 0.05,
            max_samples: 16,
        }
    }
}

/// Links in compressed rows: receiver element `i` gathers from `src[row[i]..row[i+1]]`.
///
/// Links found fully occluded carry nothing and are left out of the rows the solver reads; they
/// are kept apart (`hidden_*`), so that an edit knows each row's whole refinement without walking
/// the hierarchy again.
#[derive(Clone, Debug, Default)]
pub struct Links {
    /// Row offsets, one per element plus one.
    pub row: Vec<usize>,
    /// Source node of each link.
    pub src: Vec<u32>,
    /// Form factor of each link.
    pub ff: Vec<f32>,
    /// Row offsets of the fully occluded links, one per element plus one; empty when unknown
    /// (links from another source, such as a version-1 checkpoint).
    pub hidden_row: Vec<usize>,
    /// Source node of each fully occluded link.
    pub hidden_src: Vec<u32>,
}

impl Links {
    /// Number of links that carry light.
    pub fn len(&self) -> usize {
        self.src.len()
    }
    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.src.is_empty()
    }
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        (self.row.len() + self.hidden_row.len()) * 8
            + (self.src.len() + self.hidden_src.len()) * 4
            + self.ff.len() * 4
    }
    /// Sum of the form factors of element `i`'s row.
    pub fn row_sum(&self, i: usize) -> f64 {
        self.ff[self.row[i]..self.row[i + 1]]
            .iter()
            .map(|&f| f64::from(f))
            .sum()
    }
    /// Whether the fully occluded links are known (see [`Links::hidden_row`]).
    pub fn hidden_known(&self) -> bool {
        self.hidden_row.len() == self.row.len()
    }
}

/// The refinement oracle: split a source node while `F × bhat[node] > eps` (or, above the patch
/// level, while it exceeds `far_field × eps`).
#[derive(Clone, Copy, Debug)]
pub struct Oracle<'a> {
    /// A-priori radiosity estimate per node (max channel).
    pub bhat: &'a [f64],
    /// Threshold on `F × B̂`.
    pub eps: f64,
}

/// The rows of a range of receivers, before they are joined.
#[derive(Default)]
pub(crate) struct Chunk {
    /// Links per receiver that carry light, and fully occluded ones.
    counts: Vec<(u32, u32)>,
    src: Vec<u32>,
    ff: Vec<f32>,
    hidden: Vec<u32>,
}

impl Chunk {
    /// Ends a receiver's row: `values` by source, in order; zero ones are kept apart.
    pub(crate) fn push_row(&mut self, values: impl Iterator<Item = (u32, f32)>) {
        let (s0, h0) = (self.src.len(), self.hidden.len());
        for (s, f) in values {
            if f > 0.0 {
                self.src.push(s);
                self.ff.push(f);
            } else {
                self.hidden.push(s);
            }
        }
        self.counts.push((
            (self.src.len() - s0) as u32,
            (self.hidden.len() - h0) as u32,
        ));
    }
}

/// Receivers per parallel task.
pub(crate) const CHUNK: usize = 64;

/// Concatenates per-chunk rows into links.
pub(crate) fn assemble(n: usize, chunks: Vec<Chunk>) -> Links {
    let total: usize = chunks.iter().map(|c| c.src.len()).sum();
    let hidden: usize = chunks.iter().map(|c| c.hidden.len()).sum();
    let mut links = Links {
        row: Vec::with_capacity(n + 1),
        src: Vec::with_capacity(total),
        ff: Vec::with_capacity(total),
        hidden_row: Vec::with_capacity(n + 1),
        hidden_src: Vec::with_capacity(hidden),
    };
    links.row.push(0);
    links.hidden_row.push(0);
    for c in chunks {
        let (mut at, mut hat) = (links.src.len(), links.hidden_src.len());
        for (k, h) in c.counts {
            at += k as usize;
            hat += h as usize;
            links.row.push(at);
            links.hidden_row.push(hat);
        }
        links.src.extend(c.src);
        links.ff.extend(c.ff);
        links.hidden_src.extend(c.hidden);
    }
    links
}
