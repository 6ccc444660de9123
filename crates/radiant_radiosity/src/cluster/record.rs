//! The record of a refinement: every pair the refinement visited, depth first from the root's
//! self-link, with what it did there (cull, link, or split which end), and the links it made in
//! the same order. A geometry edit walks its own refinement beside this record: where a pair of
//! unchanged nodes meets nothing that moved, the whole of what was refined below it is copied
//! instead of refined again ([`super::refine`]).
//!
//! One byte a pair. Subtrees of at least [`SIZED_AT`] pairs also carry their size, so that
//! the walk steps over them at once; smaller ones are read through.

use super::refine::Link;

/// What the refinement did with a pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Op {
    /// Nothing flows.
    Cull,
    /// Linked, with a form factor above zero (the next of [`Record::links`]).
    Link,
    /// Linked, but nothing flows (wholly hidden): not kept.
    Zero,
    /// The receiver split into its children.
    SplitRecv,
    /// The source split into its children.
    SplitSrc,
    /// A cluster's link to itself split into its children's four links among themselves.
    SplitSelf,
}

const KIND: u8 = 7;
/// The split node has four children (a triangle), else two (a cluster).
const FOUR: u8 = 8;
/// The subtree's size is in [`Record::sized`].
const SIZED: u8 = 16;

/// Subtrees of at least this many pairs carry their size.
pub const SIZED_AT: u64 = 256;

impl Op {
    fn code(self) -> u8 {
        match self {
            Op::Cull => 0,
            Op::Link => 1,
            Op::Zero => 2,
            Op::SplitRecv => 3,
            Op::SplitSrc => 4,
            Op::SplitSelf => 5,
        }
    }

    fn from_code(c: u8) -> Op {
        match c & KIND {
            0 => Op::Cull,
            1 => Op::Link,
            2 => Op::Zero,
            3 => Op::SplitRecv,
            4 => Op::SplitSrc,
            _ => Op::SplitSelf,
        }
    }

    /// Whether this is a split.
    pub fn is_split(self) -> bool {
        matches!(self, Op::SplitRecv | Op::SplitSrc | Op::SplitSelf)
    }
}

/// The size of a subtree: its pairs, links and sized subtrees, itself included.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Extent {
    /// Pairs (bytes of [`Record::ops`]).
    pub ops: u64,
    /// Entries of [`Record::links`].
    pub links: u64,
    /// Entries of [`Record::sized`].
    pub sized: u64,
}

/// A place in a record: the pair whose op is at `ops`, the links and sized entries before it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Pos {
    /// Index into [`Record::ops`].
    pub ops: u64,
    /// Index into [`Record::links`].
    pub links: u64,
    /// Index into [`Record::sized`].
    pub sized: u64,
}

impl Pos {
    fn after(self, e: Extent) -> Pos {
        Pos {
            ops: self.ops + e.ops,
            links: self.links + e.links,
            sized: self.sized + e.sized,
        }
    }

    /// The extent from `self` to `end`.
    pub fn to(self, end: Pos) -> Extent {
        Extent {
            ops: end.ops - self.ops,
            links: end.links - self.links,
            sized: end.sized - self.sized,
        }
    }
}

/// A refinement, depth first: see the module's documentation.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Record {
    /// One byte per pair visited.
    pub ops: Vec<u8>,
    /// The links made, in the same order.
    pub links: Vec<Link>,
    /// The sizes of the subtrees of at least [`SIZED_AT`] pairs, in the order of their ops.
    pub sized: Vec<Extent>,
    /// Only the links are kept (a one-shot bake needs nothing else).
    links_only: bool,
}

impl Record {
    /// A record of the links alone: its ops and sizes stay empty.
    pub fn links_only() -> Record {
        Record {
            links_only: true,
            ..Record::default()
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> u64 {
        (self.ops.len()
            + self.links.len() * std::mem::size_of::<Link>()
            + self.sized.len() * std::mem::size_of::<Extent>()) as u64
    }

    /// The end of the record.
    pub fn end(&self) -> Pos {
        Pos {
            ops: self.ops.len() as u64,
            links: self.links.len() as u64,
            sized: self.sized.len() as u64,
        }
    }

    /// The op at `p`.
    #[inline]
    pub fn op(&self, p: Pos) -> Op {
        Op::from_code(self.ops[p.ops as usize])
    }

    /// The link of the [`Op::Link`] at `p`.
    #[inline]
    pub fn link(&self, p: Pos) -> Link {
        self.links[p.links as usize]
    }

    /// Where the first child's subtree of the split at `p` starts.
    #[inline]
    pub fn first_child(&self, p: Pos) -> Pos {
        let sized = u64::from(self.ops[p.ops as usize] & SIZED != 0);
        Pos {
            ops: p.ops + 1,
            links: p.links,
            sized: p.sized + sized,
        }
    }

    /// Where the subtree at `p` ends.
    pub fn skip(&self, p: Pos) -> Pos {
        let code = self.ops[p.ops as usize];
        if code & SIZED != 0 {
            return p.after(self.sized[p.sized as usize]);
        }
        // Small: read through (nothing below is sized).
        let mut q = p;
        let mut pending = 1u64;
        while pending > 0 {
            let code = self.ops[q.ops as usize];
            q.ops += 1;
            pending -= 1;
            match Op::from_code(code) {
                Op::Link => q.links += 1,
                Op::Cull | Op::Zero => {}
                Op::SplitSelf => pending += 4,
                Op::SplitRecv | Op::SplitSrc => pending += if code & FOUR != 0 { 4 } else { 2 },
            }
        }
        q
    }

    /// Appends a pair's op (not a split's: see [`Record::open_split`]).
    pub fn push(&mut self, op: Op, link: Option<Link>) {
        debug_assert!(!op.is_split());
        if !self.links_only {
            self.ops.push(op.code());
        }
        if let Some(l) = link {
            self.links.push(l);
        }
    }

    /// Appends a split with `children` children, before its children's subtrees; returns where
    /// it starts, for [`Record::close_split`].
    pub fn open_split(&mut self, op: Op, children: usize) -> Pos {
        debug_assert!(op.is_split());
        let start = self.end();
        if self.links_only {
            return start;
        }
        self.ops
            .push(op.code() | if children == 4 { FOUR } else { 0 });
        // Its size goes before its children's sizes: held now, dropped if it stays small.
        self.sized.push(Extent::default());
        start
    }

    /// Closes the split opened at `start`, once its children's subtrees follow it.
    pub fn close_split(&mut self, start: Pos) {
        if self.links_only {
            return;
        }
        let e = start.to(self.end());
        if e.ops >= SIZED_AT {
            self.ops[start.ops as usize] |= SIZED;
            self.sized[start.sized as usize] = e;
        } else {
            // Nothing below is sized either: the held entry is the last one.
            debug_assert_eq!(self.sized.len() as u64, start.sized + 1);
            self.sized.pop();
        }
    }

    /// Appends the subtree `[from, to)` of `other`, its links mapped by `map`.
    pub fn copy_from(&mut self, other: &Record, from: Pos, to: Pos, map: impl Fn(Link) -> Link) {
        let (o, l, s) = (
            (from.ops as usize, to.ops as usize),
            (from.links as usize, to.links as usize),
            (from.sized as usize, to.sized as usize),
        );
        self.ops.extend_from_slice(&other.ops[o.0..o.1]);
        self.links
            .extend(other.links[l.0..l.1].iter().map(|&k| map(k)));
        self.sized.extend_from_slice(&other.sized[s.0..s.1]);
    }

    /// Appends another record (a later part of the same refinement).
    pub fn append(&mut self, mut other: Record) {
        self.ops.append(&mut other.ops);
        self.links.append(&mut other.links);
        self.sized.append(&mut other.sized);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn link(r: u32) -> Link {
        Link {
            recv: r,
            src: 0,
            ff: 0.5,
        }
    }

    #[test]
    fn skip_steps_over_small_and_sized_subtrees() {
        let mut rec = Record::default();
        // A split of two: a link, then a split of four whose children are links and culls.
        let top = rec.open_split(Op::SplitRecv, 2);
        rec.push(Op::Link, Some(link(1)));
        let inner = rec.open_split(Op::SplitSrc, 4);
        rec.push(Op::Link, Some(link(2)));
        rec.push(Op::Cull, None);
        rec.push(Op::Zero, None);
        rec.push(Op::Link, Some(link(3)));
        rec.close_split(inner);
        rec.close_split(top);
        rec.push(Op::Link, Some(link(4)));
        assert!(rec.sized.is_empty());
        let end = rec.skip(Pos::default());
        assert_eq!(end.ops, 7);
        assert_eq!(end.links, 3);
        assert_eq!(rec.link(end), link(4));
        let second = rec.skip(rec.first_child(Pos::default()));
        assert_eq!(rec.op(second), Op::SplitSrc);
        assert_eq!(rec.skip(second), end);

        // A subtree large enough to be sized is stepped over by its size.
        let mut big = Record::default();
        let start = big.open_split(Op::SplitSelf, 4);
        let mut chain = Vec::new();
        for _ in 0..3 {
            big.push(Op::Cull, None);
        }
        for _ in 0..300 {
            chain.push(big.open_split(Op::SplitRecv, 2));
            big.push(Op::Link, Some(link(9)));
        }
        big.push(Op::Zero, None);
        for s in chain.into_iter().rev() {
            big.close_split(s);
        }
        big.close_split(start);
        assert_eq!(big.ops[0] & SIZED, SIZED);
        let e = big.skip(Pos::default());
        assert_eq!(e, big.end());
        assert_eq!(e.links, 300);
        // Every sized entry matches reading through.
        let mut p = big.first_child(Pos::default());
        for _ in 0..3 {
            p = big.skip(p);
        }
        assert_eq!(big.skip(p), big.end());
    }
}
