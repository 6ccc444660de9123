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

/// [`Record::assemble_over`] sets aside at most this share of the old record (stretches out of
/// its order); with more, a record in fresh memory is no dearer.
pub const ASIDE_AT_MOST: f64 = 0.5;

/// Calls its argument with `(from, to, place)` of each old stretch that stays, first to last
/// (`false`) or last to first (`true`).
type Staying<'a> = dyn Fn(bool, &mut dyn FnMut(Pos, Pos, Pos)) + Sync + 'a;

/// Moves the stretches of one of a record's arrays (`pick` reads their places in it) that
/// `each` yields, each element through `map`: those moving left (or staying put), first to
/// last, then those moving right, last to first. The stretches are in order and apart both
/// where they come from and where they go, so none overwrites what is still to be read.
fn shift<T: Copy>(
    arr: &mut [T],
    pick: fn(Pos) -> u64,
    map: Option<&(dyn Fn(T) -> T + Sync)>,
    each: &Staying<'_>,
) {
    for back in [false, true] {
        each(back, &mut |a, b, to| {
            let (x, y, t) = (pick(a) as usize, pick(b) as usize, pick(to) as usize);
            if back != (t > x) {
                return;
            }
            match map {
                None if t != x => arr.copy_within(x..y, t),
                None => {}
                Some(m) if back => (0..y - x).rev().for_each(|i| arr[t + i] = m(arr[x + i])),
                Some(m) => (0..y - x).for_each(|i| arr[t + i] = m(arr[x + i])),
            }
        });
    }
}

/// Which of the stretches `[from, to)` of one record that `olds` yields (`n` of them, in the
/// order they are written) stay in place in [`Record::assemble_over`]: a heaviest run of them
/// (by bytes) that is in the record's own order, its stretches apart, found as a weighted
/// longest increasing subsequence over a Fenwick tree of prefix maxima, `O(n log n)` time and
/// about 30 bytes a stretch; `None` when that memory cannot be had.
fn in_order<I: Iterator<Item = (Pos, Pos)>>(olds: impl Fn() -> I, n: usize) -> Option<Vec<bool>> {
    // A stretch may follow one that ends at or before its start (the three counts of a place
    // in one record rise together, so its pairs' count orders it).
    let mut ends: Vec<u64> = Vec::new();
    ends.try_reserve_exact(n).ok()?;
    ends.extend(olds().map(|(_, b)| b.ops));
    ends.sort_unstable();
    ends.dedup();
    let weight = |a: Pos, b: Pos| Record::bytes_of(a.to(b)) + 1;
    // Per end rank: the heaviest run ending at or before it, and its last stretch.
    let mut tree: Vec<(u64, u32)> = Vec::new();
    tree.try_reserve_exact(ends.len() + 1).ok()?;
    tree.resize(ends.len() + 1, (0, u32::MAX));
    let mut prev: Vec<u32> = Vec::new();
    prev.try_reserve_exact(n).ok()?;
    let mut best = (0u64, u32::MAX);
    for (i, (a, b)) in olds().enumerate() {
        let mut r = ends.partition_point(|&e| e <= a.ops);
        let mut found = (0u64, u32::MAX);
        while r > 0 {
            if tree[r].0 > found.0 {
                found = tree[r];
            }
            r &= r - 1;
        }
        prev.push(found.1);
        let run = (found.0 + weight(a, b), i as u32);
        if run.0 > best.0 {
            best = run;
        }
        let mut r = ends.partition_point(|&e| e < b.ops) + 1;
        while r < tree.len() {
            if run.0 > tree[r].0 {
                tree[r] = run;
            }
            r += r & r.wrapping_neg();
        }
    }
    drop((ends, tree));
    let mut keep = vec![false; n];
    let mut at = best.1;
    while at != u32::MAX {
        keep[at as usize] = true;
        at = prev[at as usize];
    }
    Some(keep)
}

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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Zeroable)]
#[repr(C)]
pub struct Extent {
    /// Pairs (bytes of [`Record::ops`]).
    pub ops: u64,
    /// Entries of [`Record::links`].
    pub links: u64,
    /// Entries of [`Record::sized`].
    pub sized: u64,
}

impl std::ops::Add for Extent {
    type Output = Extent;
    fn add(self, o: Extent) -> Extent {
        Extent {
            ops: self.ops + o.ops,
            links: self.links + o.links,
            sized: self.sized + o.sized,
        }
    }
}

impl std::ops::Sub for Extent {
    type Output = Extent;
    fn sub(self, o: Extent) -> Extent {
        Extent {
            ops: self.ops - o.ops,
            links: self.links - o.links,
            sized: self.sized - o.sized,
        }
    }
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

    fn before(self, e: Extent) -> Pos {
        Pos {
            ops: self.ops - e.ops,
            links: self.links - e.links,
            sized: self.sized - e.sized,
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
        Record::bytes_of(Pos::default().to(self.end()))
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
        self.close_split_holding(start, Extent::default());
    }

    /// [`Record::close_split`] for a split whose subtree also holds `held` that is not written
    /// here yet (a [`Piece`]'s stretches of another record).
    fn close_split_holding(&mut self, start: Pos, held: Extent) {
        if self.links_only {
            return;
        }
        let e = start.to(self.end()) + held;
        if e.ops >= SIZED_AT {
            self.ops[start.ops as usize] |= SIZED;
            self.sized[start.sized as usize] = e;
        } else {
            // Nothing below is sized either: the held entry is the last one.
            debug_assert_eq!(self.sized.len() as u64, start.sized + 1);
            self.sized.pop();
        }
    }

    /// Appends another record (a later part of the same refinement).
    pub fn append(&mut self, mut other: Record) {
        self.ops.append(&mut other.ops);
        self.links.append(&mut other.links);
        self.sized.append(&mut other.sized);
    }

    /// The record of a refinement made in parts: `top`, depth first, holds the splits above
    /// the parts and where each of `pieces` goes; the stretches the pieces hold of `old` (an
    /// edit's record before it) are copied in with their links mapped by `remap`. Every part is
    /// written once, in parallel, into memory the allocator hands over zeroed and untouched
    /// (so the kernel's zeroing of fresh pages is spread over the threads too). `None` when
    /// the memory cannot be had.
    pub fn assemble(
        top: &[Top],
        pieces: &[Piece],
        links_only: bool,
        old: Option<(&Record, &(dyn Fn(Link) -> Link + Sync))>,
    ) -> Option<Record> {
        use rayon::prelude::*;
        let kept = |e: Extent| kept(e, links_only);
        let jobs = layout(top, pieces, links_only)?;
        let total = jobs.iter().fold(Extent::default(), |a, j| a + j.1);
        let mut out = Record {
            ops: bytemuck::allocation::try_zeroed_vec(total.ops as usize).ok()?,
            links: bytemuck::allocation::try_zeroed_vec(total.links as usize).ok()?,
            sized: bytemuck::allocation::try_zeroed_vec(total.sized as usize).ok()?,
            links_only,
        };
        // Disjoint places for the parts, then every part written at once.
        type Place<'o> = (&'o mut [u8], &'o mut [Link], &'o mut [Extent]);
        fn take<'o>(place: &mut Place<'o>, e: Extent) -> Place<'o> {
            let (a, o) = std::mem::take(&mut place.0).split_at_mut(e.ops as usize);
            let (b, l) = std::mem::take(&mut place.1).split_at_mut(e.links as usize);
            let (c, z) = std::mem::take(&mut place.2).split_at_mut(e.sized as usize);
            *place = (o, l, z);
            (a, b, c)
        }
        let mut rest: Place<'_> = (&mut out.ops[..], &mut out.links[..], &mut out.sized[..]);
        let mut work = Vec::with_capacity(jobs.len());
        for (job, e) in jobs {
            work.push((job, take(&mut rest, e)));
        }
        // Copies `[from, to)` of `rec` to the front of `place`, its links mapped by `map`.
        let copy = |place: &mut Place<'_>,
                    rec: &Record,
                    from: Pos,
                    to: Pos,
                    map: Option<&dyn Fn(Link) -> Link>| {
            let (o, l, z) = take(place, kept(from.to(to)));
            if !links_only {
                o.copy_from_slice(&rec.ops[from.ops as usize..to.ops as usize]);
                z.copy_from_slice(&rec.sized[from.sized as usize..to.sized as usize]);
            }
            let src = &rec.links[from.links as usize..to.links as usize];
            match map {
                Some(m) => l.iter_mut().zip(src).for_each(|(d, s)| *d = m(*s)),
                None => l.copy_from_slice(src),
            }
        };
        let missing = std::sync::atomic::AtomicBool::new(false);
        work.into_par_iter()
            .with_max_len(1)
            .for_each(|(job, mut place)| match job {
                Job::Split(code, e) => {
                    place.0[0] = code;
                    if let Some(e) = e {
                        place.2[0] = e;
                    }
                }
                Job::Piece(piece) => {
                    let mut at = Pos::default();
                    for h in &piece.holes {
                        copy(&mut place, &piece.own, at, h.at, None);
                        let Some((rec, remap)) = old else {
                            missing.store(true, std::sync::atomic::Ordering::Relaxed);
                            return;
                        };
                        copy(&mut place, rec, h.from, h.to, Some(remap));
                        at = h.at;
                    }
                    copy(&mut place, &piece.own, at, piece.own.end(), None);
                }
            });
        (!missing.into_inner()).then_some(out)
    }

    /// The size of the record [`Record::assemble`] makes of these parts; `None` when the top
    /// does not close every split it opens.
    pub fn extent_of(top: &[Top], pieces: &[Piece], links_only: bool) -> Option<Extent> {
        let jobs = layout(top, pieces, links_only)?;
        Some(jobs.iter().fold(Extent::default(), |a, j| a + j.1))
    }

    /// Bytes a record of this size holds (as [`Record::bytes`]).
    pub fn bytes_of(e: Extent) -> u64 {
        e.ops
            + e.links * std::mem::size_of::<Link>() as u64
            + e.sized * std::mem::size_of::<Extent>() as u64
    }

    /// [`Record::assemble`] into the memory of `old`, the record the pieces hold stretches of,
    /// which becomes the assembled record: those stretches move to their new places (their
    /// links mapped by `remap`) and what the pieces made themselves is written around them.
    /// An edit's record is mostly the one before it, so this takes little memory beyond what
    /// the record grows by: on the 2-core virtual machine of ARCHITECTURE.md's figures, fresh
    /// pages cost about a second per gigabyte to touch (nine the first time), and a level
    /// edit's new record was half a gigabyte held beside the old one. Stretches out of `old`'s
    /// order (an edit that reordered the tree around what moved) are copied aside first; the
    /// others move in place. `false`, with `old` as it was, when it should not be done: the
    /// pieces or `old` hold links alone, a stretch is not inside `old`, more than
    /// [`ASIDE_AT_MOST`] of it would be set aside, or memory cannot be had. The same record
    /// as [`Record::assemble`] either way.
    pub fn assemble_over(
        top: &[Top],
        pieces: &[Piece],
        old: &mut Record,
        remap: &(dyn Fn(Link) -> Link + Sync),
    ) -> bool {
        if old.links_only || pieces.iter().any(|p| p.own.links_only) {
            return false;
        }
        let Some(jobs) = layout(top, pieces, false) else {
            return false;
        };
        let end = old.end();
        // Where each job starts; every old stretch inside the old record.
        let mut starts = Vec::with_capacity(jobs.len());
        let mut at = Pos::default();
        for (_, e) in &jobs {
            starts.push(at);
            at = at.after(*e);
        }
        let olds = || {
            jobs.iter()
                .filter_map(|(j, _)| match j {
                    Job::Piece(p) => Some(p.holes.iter().map(|h| (h.from, h.to))),
                    Job::Split(..) => None,
                })
                .flatten()
        };
        let within = |a: Pos, b: Pos| {
            a.ops <= b.ops
                && a.links <= b.links
                && a.sized <= b.sized
                && b.ops <= end.ops
                && b.links <= end.links
                && b.sized <= end.sized
        };
        if !olds().all(|(a, b)| within(a, b)) {
            return false;
        }
        let holes = olds().count();
        // Which stay: each that follows the last one kept, when that sets little aside (a
        // level edit: 1 MB of 0.5 GB), else the heaviest run of them in the old order.
        let aside_of = |stay: &[bool]| {
            let mut e = Extent::default();
            for ((a, b), &keep) in olds().zip(stay) {
                if !keep {
                    e = e + a.to(b);
                }
            }
            e
        };
        let mut stay = Vec::new();
        if stay.try_reserve_exact(holes).is_err() {
            return false;
        }
        let mut last = Pos::default();
        stay.extend(olds().map(|(a, b)| {
            let keep = a.ops >= last.ops && a.links >= last.links && a.sized >= last.sized;
            if keep {
                last = b;
            }
            keep
        }));
        let mut aside_size = aside_of(&stay);
        if Record::bytes_of(aside_size) > old.bytes() / 64 {
            let Some(run) = in_order(olds, holes) else {
                return false;
            };
            let e = aside_of(&run);
            if Record::bytes_of(e) < Record::bytes_of(aside_size) {
                (stay, aside_size) = (run, e);
            }
        }
        let total = at;
        if Record::bytes_of(aside_size) as f64 > ASIDE_AT_MOST * old.bytes() as f64 {
            return false;
        }
        let more = |len: usize, want: u64| (want as usize).saturating_sub(len);
        let mut aside = Record::default();
        if old
            .ops
            .try_reserve_exact(more(old.ops.len(), total.ops))
            .is_err()
            || (old.links)
                .try_reserve_exact(more(old.links.len(), total.links))
                .is_err()
            || (old.sized)
                .try_reserve_exact(more(old.sized.len(), total.sized))
                .is_err()
            || aside
                .ops
                .try_reserve_exact(aside_size.ops as usize)
                .is_err()
            || (aside.links)
                .try_reserve_exact(aside_size.links as usize)
                .is_err()
            || (aside.sized)
                .try_reserve_exact(aside_size.sized as usize)
                .is_err()
        {
            return false;
        }
        // Set aside what is out of order, before anything moves.
        for ((a, b), &keep) in olds().zip(&stay) {
            if !keep {
                let g = |x: u64, y: u64| x as usize..y as usize;
                aside.ops.extend_from_slice(&old.ops[g(a.ops, b.ops)]);
                let links = &old.links[g(a.links, b.links)];
                aside.links.extend(links.iter().map(|&l| remap(l)));
                aside
                    .sized
                    .extend_from_slice(&old.sized[g(a.sized, b.sized)]);
            }
        }
        let (n_ops, n_links, n_sized) = (
            total.ops as usize,
            total.links as usize,
            total.sized as usize,
        );
        old.ops.resize(old.ops.len().max(n_ops), 0);
        let blank = Link {
            recv: 0,
            src: 0,
            ff: 0.0,
        };
        old.links.resize(old.links.len().max(n_links), blank);
        old.sized
            .resize(old.sized.len().max(n_sized), Extent::default());
        // Each old stretch with its place, `f(hole, from, to, place)` (`hole` its number among
        // them all), first to last or last to first: a piece's own stretches lie around them.
        let each = |back: bool, f: &mut dyn FnMut(usize, Pos, Pos, Pos)| {
            let mut hole = if back { holes } else { 0 };
            for k in 0..jobs.len() {
                let k = if back { jobs.len() - 1 - k } else { k };
                let (Job::Piece(piece), e) = jobs[k] else {
                    continue;
                };
                if back {
                    // From the job's end: its own stretch after each old one comes first.
                    let (mut end, mut own) = (starts[k].after(e), piece.own.end());
                    for h in piece.holes.iter().rev() {
                        hole -= 1;
                        end = end.before(h.at.to(own)).before(h.from.to(h.to));
                        f(hole, h.from, h.to, end);
                        own = h.at;
                    }
                } else {
                    let (mut at, mut own) = (starts[k], Pos::default());
                    for h in &piece.holes {
                        at = at.after(own.to(h.at));
                        f(hole, h.from, h.to, at);
                        at = at.after(h.from.to(h.to));
                        own = h.at;
                        hole += 1;
                    }
                }
            }
        };
        let staying = |back: bool, f: &mut dyn FnMut(Pos, Pos, Pos)| {
            each(back, &mut |h, a, b, to| {
                if stay[h] {
                    f(a, b, to);
                }
            });
        };
        // The stretches that stay move, each array on its own thread.
        let (ops, links, sized) = (&mut old.ops, &mut old.links, &mut old.sized);
        rayon::join(
            || shift(ops, |p| p.ops, None, &staying),
            || {
                rayon::join(
                    || shift(links, |p| p.links, Some(remap), &staying),
                    || shift(sized, |p| p.sized, None, &staying),
                )
            },
        );
        // Then what was set aside, and what the pieces made themselves, around them.
        let put = |old: &mut Record, rec: &Record, a: Pos, b: Pos, to: Pos| {
            let g = |x: u64, y: u64| x as usize..y as usize;
            let d = |at: u64, x: u64, y: u64| at as usize..(at + y - x) as usize;
            old.ops[d(to.ops, a.ops, b.ops)].copy_from_slice(&rec.ops[g(a.ops, b.ops)]);
            old.links[d(to.links, a.links, b.links)]
                .copy_from_slice(&rec.links[g(a.links, b.links)]);
            old.sized[d(to.sized, a.sized, b.sized)]
                .copy_from_slice(&rec.sized[g(a.sized, b.sized)]);
        };
        let mut set = Pos::default();
        each(false, &mut |h, a, b, to| {
            if !stay[h] {
                let next = set.after(a.to(b));
                put(old, &aside, set, next, to);
                set = next;
            }
        });
        for (k, (job, _)) in jobs.iter().enumerate() {
            let to = starts[k];
            match *job {
                Job::Split(code, e) => {
                    old.ops[to.ops as usize] = code;
                    if let Some(e) = e {
                        old.sized[to.sized as usize] = e;
                    }
                }
                Job::Piece(piece) => {
                    let (mut at, mut own) = (to, Pos::default());
                    for h in &piece.holes {
                        put(old, &piece.own, own, h.at, at);
                        at = at.after(own.to(h.at)).after(h.from.to(h.to));
                        own = h.at;
                    }
                    put(old, &piece.own, own, piece.own.end(), at);
                }
            }
        }
        old.ops.truncate(n_ops);
        old.links.truncate(n_links);
        old.sized.truncate(n_sized);
        true
    }
}

/// `e` as a record of the links alone holds it (`links_only`), or whole.
fn kept(e: Extent, links_only: bool) -> Extent {
    if links_only {
        Extent {
            links: e.links,
            ..Extent::default()
        }
    } else {
        e
    }
}

/// A part of an assembled record ([`layout`]): a split's own entry (its op code, and its size
/// when sized), or a piece with its stretches.
enum Job<'p> {
    Split(u8, Option<Extent>),
    Piece(&'p Piece),
}

/// The parts of a refinement made in parts, in order, each with its extent; `None` when the
/// top does not close every split it opens.
fn layout<'p>(
    top: &[Top],
    pieces: &'p [Piece],
    links_only: bool,
) -> Option<Vec<(Job<'p>, Extent)>> {
    let kept = |e: Extent| kept(e, links_only);
    // The extents of the top's splits, and whether each is sized.
    let mut split_extent = vec![(Extent::default(), false); top.len()];
    let mut open: Vec<(usize, Extent)> = Vec::new();
    let mut sum = Extent::default();
    for (i, t) in top.iter().enumerate() {
        match *t {
            Top::Open(..) => {
                open.push((i, sum));
                sum = Extent::default();
            }
            Top::Piece(p) => sum = sum + kept(pieces.get(p)?.extent()),
            Top::Close => {
                let (at, outer) = open.pop()?;
                let mut e = sum
                    + kept(Extent {
                        ops: 1,
                        links: 0,
                        sized: 1,
                    });
                let sized = e.ops >= SIZED_AT && !links_only;
                if !sized {
                    e.sized -= u64::from(!links_only);
                }
                split_extent[at] = (e, sized);
                sum = outer + e;
            }
        }
    }
    let mut jobs = Vec::with_capacity(top.len());
    for (i, t) in top.iter().enumerate() {
        match *t {
            Top::Open(op, n) => {
                let (e, sized) = split_extent[i];
                let code =
                    op.code() | if n == 4 { FOUR } else { 0 } | if sized { SIZED } else { 0 };
                let size = Extent {
                    ops: 1,
                    links: 0,
                    sized: u64::from(sized),
                };
                if !links_only {
                    jobs.push((Job::Split(code, sized.then_some(e)), size));
                }
            }
            Top::Piece(p) => jobs.push((Job::Piece(&pieces[p]), kept(pieces[p].extent()))),
            Top::Close => {}
        }
    }
    Some(jobs)
}

impl Record {
    /// A record from its ops and sizes (a checkpoint's), its links found by walking the pairs
    /// from `root`'s self-link (`children(node)`: a node's children, none for an element) and
    /// taking each link's form factor from `ff(r, s)`. `None` unless the ops make one whole
    /// refinement whose sized subtrees, and only those, have the sizes in `sized`.
    pub fn rebuilt(
        ops: Vec<u8>,
        sized: Vec<Extent>,
        root: u32,
        children: impl Fn(u32) -> ([u32; 4], usize),
        ff: impl Fn(u32, u32) -> f32,
    ) -> Option<Record> {
        let mut links = Vec::new();
        let mut stack = vec![(root, root)];
        // Open splits: where each starts, its children still to come, its sized entry.
        let mut open: Vec<(Pos, usize, Option<usize>)> = Vec::new();
        let mut pos = Pos::default();
        for &code in &ops {
            let (r, s) = stack.pop()?;
            let start = pos;
            pos.ops += 1;
            let sized_at = (code & SIZED != 0).then_some(pos.sized as usize);
            pos.sized += u64::from(sized_at.is_some());
            let op = Op::from_code(code);
            let want = if code & FOUR != 0 { 4 } else { 2 };
            let split = |n: u32| {
                let (c, k) = children(n);
                (k == want).then_some((c, k))
            };
            let n = match op {
                Op::Link => {
                    links.push(Link {
                        recv: r,
                        src: s,
                        ff: ff(r, s),
                    });
                    pos.links += 1;
                    0
                }
                Op::Cull | Op::Zero => 0,
                Op::SplitSelf => {
                    let (c, k) = children(r);
                    if k != 2 || r != s {
                        return None;
                    }
                    let (a, b) = (c[0], c[1]);
                    stack.extend([(b, b), (b, a), (a, b), (a, a)]);
                    4
                }
                Op::SplitRecv => {
                    let (c, k) = split(r)?;
                    stack.extend(c[..k].iter().rev().map(|&x| (x, s)));
                    k
                }
                Op::SplitSrc => {
                    let (c, k) = split(s)?;
                    stack.extend(c[..k].iter().rev().map(|&x| (r, x)));
                    k
                }
            };
            if n > 0 {
                open.push((start, n, sized_at));
                continue;
            }
            if sized_at.is_some() {
                return None;
            }
            // A subtree ended: so may the splits above it, each held to its size.
            while let Some(top) = open.last_mut() {
                top.1 -= 1;
                if top.1 > 0 {
                    break;
                }
                let (start, _, at) = open.pop()?;
                let e = start.to(pos);
                let fits = match at {
                    Some(i) => e.ops >= SIZED_AT && sized.get(i) == Some(&e),
                    None => e.ops < SIZED_AT,
                };
                if !fits {
                    return None;
                }
            }
        }
        (stack.is_empty() && open.is_empty() && pos.sized == sized.len() as u64).then_some(Record {
            ops,
            links,
            sized,
            links_only: false,
        })
    }
}

/// The top of a refinement made in parts, depth first ([`Record::assemble`]).
#[derive(Clone, Copy, Debug)]
pub enum Top {
    /// A split into this many children, whose entries follow up to its [`Top::Close`].
    Open(Op, usize),
    /// The piece of this number.
    Piece(usize),
    /// The end of the last open split.
    Close,
}

/// A part of a refinement made on its own: its own ops, links and sizes, and stretches of
/// another record (an edit's record before it) that go in between, copied only when the parts
/// are put together ([`Record::assemble`]), so that what an edit keeps is copied once.
#[derive(Debug, Default)]
pub struct Piece {
    /// What this part made itself.
    pub own: Record,
    /// Stretches of the other record, in order.
    holes: Vec<Hole>,
    /// Their extents, summed.
    held: Extent,
}

/// A stretch `[from, to)` of another record that goes where `own` is at `at`.
#[derive(Clone, Copy, Debug)]
struct Hole {
    at: Pos,
    from: Pos,
    to: Pos,
}

/// Where a [`Piece`]'s split was opened.
#[derive(Clone, Copy, Debug)]
pub struct Opened {
    own: Pos,
    held: Extent,
    holes: usize,
}

impl Piece {
    /// A piece writing into `own` (whole, or links alone).
    pub fn new(own: Record) -> Piece {
        Piece {
            own,
            holes: Vec::new(),
            held: Extent::default(),
        }
    }

    /// Its size with the stretches it holds.
    pub fn extent(&self) -> Extent {
        Pos::default().to(self.own.end()) + self.held
    }

    /// As [`Record::push`].
    pub fn push(&mut self, op: Op, link: Option<Link>) {
        self.own.push(op, link);
    }

    /// As [`Record::open_split`].
    pub fn open_split(&mut self, op: Op, children: usize) -> Opened {
        Opened {
            own: self.own.open_split(op, children),
            held: self.held,
            holes: self.holes.len(),
        }
    }

    /// As [`Record::close_split`].
    pub fn close_split(&mut self, start: Opened) {
        let sized = self.own.sized.len();
        self.own
            .close_split_holding(start.own, self.held - start.held);
        if self.own.sized.len() < sized {
            // The split stayed small: the size held for it went, and the stretches below it
            // (themselves small, nothing sized in them) move up one sized entry.
            for h in &mut self.holes[start.holes..] {
                h.at.sized -= 1;
            }
        }
    }

    /// The subtree `[from, to)` of the other record goes here.
    pub fn copy_from(&mut self, from: Pos, to: Pos) {
        self.holes.push(Hole {
            at: self.own.end(),
            from,
            to,
        });
        self.held = self.held + from.to(to);
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

    /// A small subtree (a split of two) and a sized one (a chain of 300 splits), their links'
    /// receivers offset by `k`.
    fn small(rec: &mut Record, k: u32) {
        let s = rec.open_split(Op::SplitRecv, 2);
        rec.push(Op::Link, Some(link(1 + k)));
        rec.push(Op::Cull, None);
        rec.close_split(s);
    }

    fn large(rec: &mut Record, k: u32) {
        let mut chain = Vec::new();
        for i in 0..300 {
            chain.push(rec.open_split(Op::SplitRecv, 2));
            rec.push(Op::Link, Some(link(i + k)));
        }
        rec.push(Op::Zero, None);
        for s in chain.into_iter().rev() {
            rec.close_split(s);
        }
    }

    #[test]
    fn a_record_is_rebuilt_from_its_ops_and_sizes_and_refused_when_they_disagree() {
        // Any consistent tree will do: node n splits into n + 10⁶ (an element) and n + 1.
        let children = |n: u32| {
            if n < 1_000_000 {
                ([n + 1_000_000, n + 1, 0, 0], 2)
            } else {
                ([0; 4], 0)
            }
        };
        let mut rec = Record::default();
        large(&mut rec, 0);
        assert!(!rec.sized.is_empty());
        let ff = |r: u32, s: u32| (r + s) as f32;
        let again =
            Record::rebuilt(rec.ops.clone(), rec.sized.clone(), 0, children, ff).expect("rebuilt");
        assert_eq!((&again.ops, &again.sized), (&rec.ops, &rec.sized));
        assert_eq!(again.links.len(), rec.links.len());
        assert!(again.links.iter().all(|l| l.ff == (l.recv + l.src) as f32));
        // A size that is not its subtree's, a size flag taken away or added, ops cut short:
        // refused, not read past.
        let mut sized = rec.sized.clone();
        sized[3].ops += 1;
        assert!(Record::rebuilt(rec.ops.clone(), sized, 0, children, ff).is_none());
        let mut ops = rec.ops.clone();
        ops[0] &= !SIZED;
        assert!(Record::rebuilt(ops, rec.sized.clone(), 0, children, ff).is_none());
        let mut ops = rec.ops.clone();
        let last = ops.len() - 1;
        ops[last] |= SIZED;
        assert!(Record::rebuilt(ops, rec.sized.clone(), 0, children, ff).is_none());
        let cut = rec.ops[..rec.ops.len() - 1].to_vec();
        assert!(Record::rebuilt(cut, rec.sized.clone(), 0, children, ff).is_none());
    }

    #[test]
    fn pieces_with_stretches_of_another_record_assemble_as_if_written_in_one() {
        let mut old = Record::default();
        small(&mut old, 0);
        large(&mut old, 0);
        let a = (Pos::default(), old.skip(Pos::default()));
        let b = (a.1, old.skip(a.1));
        assert_eq!(b.1, old.end());
        let remap = |l: Link| Link {
            recv: l.recv + 100,
            ..l
        };
        for links_only in [false, true] {
            let blank = || {
                if links_only {
                    Record::links_only()
                } else {
                    Record::default()
                }
            };
            // Written in one.
            let mut want = blank();
            let top = want.open_split(Op::SplitSelf, 4);
            let s = want.open_split(Op::SplitSrc, 2);
            small(&mut want, 100);
            want.push(Op::Link, Some(link(5)));
            want.close_split(s);
            large(&mut want, 100);
            want.push(Op::Zero, None);
            small(&mut want, 100);
            large(&mut want, 100);
            let s = want.open_split(Op::SplitRecv, 2);
            small(&mut want, 100);
            want.push(Op::Cull, None);
            want.close_split(s);
            want.close_split(top);

            // The same in four pieces under a split, the old subtrees held, not copied: in a
            // small split (whose held size goes), alone, two in a row, and first in a split.
            let mut p = [(); 4].map(|_| Piece::new(blank()));
            let s = p[0].open_split(Op::SplitSrc, 2);
            p[0].copy_from(a.0, a.1);
            p[0].push(Op::Link, Some(link(5)));
            p[0].close_split(s);
            p[1].copy_from(b.0, b.1);
            p[2].push(Op::Zero, None);
            p[2].copy_from(a.0, a.1);
            p[2].copy_from(b.0, b.1);
            let s = p[3].open_split(Op::SplitRecv, 2);
            p[3].copy_from(a.0, a.1);
            p[3].push(Op::Cull, None);
            p[3].close_split(s);
            let parts = [
                Top::Open(Op::SplitSelf, 4),
                Top::Piece(0),
                Top::Piece(1),
                Top::Piece(2),
                Top::Piece(3),
                Top::Close,
            ];
            let got = Record::assemble(&parts, &p, links_only, Some((&old, &remap)));
            assert_eq!(got.as_ref(), Some(&want), "links only: {links_only}");
            // Without the other record, nothing is made up for its stretches.
            assert!(Record::assemble(&parts, &p, links_only, None).is_none());
            // Over the old record's memory: refused, the old record left as it was, for pieces
            // of links alone, and here for more than half of it out of order (the large
            // subtree used twice).
            let mut over = old.clone();
            assert!(!Record::assemble_over(&parts, &p, &mut over, &remap));
            assert_eq!(over, old);
        }
    }

    #[test]
    fn assembled_over_the_old_record_as_into_fresh_memory() {
        let mut old = Record::default();
        small(&mut old, 0);
        large(&mut old, 0);
        small(&mut old, 7);
        large(&mut old, 7);
        let (mut cuts, mut at) = (vec![Pos::default()], Pos::default());
        while at != old.end() {
            at = old.skip(at);
            cuts.push(at);
        }
        assert_eq!(cuts.len(), 5);
        let stretch = |k: usize| (cuts[k], cuts[k + 1]);
        let remap = |l: Link| Link {
            recv: l.recv * 3 + 1,
            ..l
        };
        // Pieces that keep some of the old subtrees, in order, and add their own before,
        // between and after them: the new record longer than the old (its stretches move
        // right), shorter (they move left), or both in turn.
        type Plan = Vec<Vec<Result<usize, u32>>>;
        let plans: Vec<Plan> = vec![
            vec![vec![Ok(0), Ok(1)], vec![Err(1)], vec![Ok(2), Ok(3)]],
            vec![
                vec![Err(2), Err(3), Ok(0)],
                vec![Ok(1), Err(1)],
                vec![Ok(3)],
            ],
            vec![vec![Ok(1)], vec![Ok(3)]],
            vec![vec![Ok(0)], vec![], vec![Err(3), Ok(2), Ok(3)]],
            vec![vec![Err(1), Err(2)], vec![Err(3)]],
            // Out of the old order: the small subtrees are set aside, the large ones move in
            // place.
            vec![vec![Ok(1)], vec![Ok(0), Err(2)], vec![Ok(3), Ok(2)]],
            vec![vec![Ok(1), Ok(0)], vec![Err(1), Ok(3), Ok(2), Ok(2)]],
        ];
        for plan in plans {
            let mut p: Vec<Piece> = Vec::new();
            let mut parts = vec![Top::Open(Op::SplitSelf, plan.len())];
            for (i, items) in plan.iter().enumerate() {
                let mut piece = Piece::new(Record::default());
                let s = piece.open_split(Op::SplitRecv, 2);
                for item in items {
                    match *item {
                        Ok(k) => piece.copy_from(stretch(k).0, stretch(k).1),
                        Err(1) => small(&mut piece.own, 50),
                        Err(2) => large(&mut piece.own, 60),
                        Err(_) => piece.push(Op::Link, Some(link(70))),
                    }
                }
                piece.push(Op::Cull, None);
                piece.close_split(s);
                p.push(piece);
                parts.push(Top::Piece(i));
            }
            parts.push(Top::Close);
            let want = Record::assemble(&parts, &p, false, Some((&old, &remap))).expect("fresh");
            let mut over = old.clone();
            assert!(
                Record::assemble_over(&parts, &p, &mut over, &remap),
                "{plan:?}"
            );
            assert_eq!(over, want, "{plan:?}");
        }
        // The large subtrees used four times: more than half set aside, refused, the old
        // record as it was.
        let mut p = Piece::new(Record::default());
        for k in [3, 3, 1, 1] {
            p.copy_from(stretch(k).0, stretch(k).1);
        }
        let parts = [Top::Piece(0)];
        let mut over = old.clone();
        assert!(!Record::assemble_over(&parts, &[p], &mut over, &remap));
        assert_eq!(over, old);
    }

    #[test]
    fn the_heaviest_run_in_order_stays() {
        let at = |ops: u64| Pos {
            ops,
            links: ops / 2,
            sized: 0,
        };
        let run = |st: &[(u64, u64)]| {
            let v: Vec<(Pos, Pos)> = st.iter().map(|&(a, b)| (at(a), at(b))).collect();
            in_order(|| v.iter().copied(), v.len()).expect("memory")
        };
        // Written in the order 100-110, 0-90, 90-100, 110-120: the long stretch leads the run
        // that stays, the short one before it is set aside (taking the first that comes, as
        // a greedy choice would, sets aside the long one).
        assert_eq!(
            run(&[(100, 110), (0, 90), (90, 100), (110, 120)]),
            [false, true, true, true]
        );
        // A stretch used twice stays once; one inside another cannot follow it.
        assert_eq!(run(&[(0, 50), (0, 50)]), [true, false]);
        assert_eq!(run(&[(0, 50), (10, 20)]), [true, false]);
        // Empty stretches go anywhere in order.
        assert_eq!(run(&[(5, 5), (0, 5), (5, 5)]), [false, true, true]);
        assert!(run(&[]).is_empty());
    }
}
