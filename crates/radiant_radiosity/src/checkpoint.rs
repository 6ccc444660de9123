//! Bake checkpoints: the links (form factors), the enclosed-element flags (clustered: each
//! element's exposure) and the solution, written atomically, so a long bake resumes after a
//! restart without recomputing form factors.
//! Versions 1 and 2 hold a per-triangle hierarchy ([`read`](read()), [`write`](write())), versions 3 and 4 a
//! clustered one ([`read_clustered`], [`write_clustered`]); each reader refuses the other's
//! files with [`BakeError::CheckpointHierarchy`].
//!
//! Version 4, little-endian: the magic and version; the fingerprint, element, node (mesh nodes
//! and clusters) and link counts, and the refinement threshold the links were built with; row
//! offsets (u64, one per node and one more), sources (u32), form factors (f32), each element's
//! exposed probe points (u8, of [`crate::exposure::POINTS`]), radiosity (3 × f64 per element);
//! where the bake kept it for geometry edits, the
//! refinement's record: a hash of the estimates it was refined with, its op and sized-subtree
//! counts (u64), ops (u8), sized subtrees (3 × u64; its links are the rows' links, found again
//! by walking the ops); an FNV-1a checksum. A
//! file without the record (older, or from a one-shot bake) resumes all the same, and makes
//! the refinement again at its first geometry edit.
//!
//! Layout (version 2), little-endian: 16-byte magic and version; the fingerprint of the
//! geometry, lights and every parameter the links depend on; element, node, link and fully
//! occluded link counts, and flags (1: the occluded links are stored, 2: the refinement oracle
//! is); row offsets (u64), sources (u32), form factors (f32), enclosed flags (u8), radiosity
//! (3 × f64 per element); the occluded links' row offsets (u64) and sources (u32); the oracle's
//! threshold and per-node estimates (f64); an FNV-1a checksum of all of it. Version 1 (no counts
//! of occluded links, no flags, nothing after the radiosity) is still read: edits after such a
//! resume walk every row again. Materials and lights are not in the fingerprint: a checkpoint of
//! the same geometry with other colours or lights resumes as an edit would.

use std::io::Write;
use std::path::Path;

use crate::BakeError;
use crate::cluster::record::Extent;
use crate::cluster::solve::{Rows, RowsRef};
use crate::hierarchy::{Estimates, Hierarchy};
use crate::links::Links;
use crate::mesh::Mesh;
use crate::rng::Fnv;
use crate::system::Rgb;

/// The magic, without its last byte: the version.
/// Why a checkpoint cannot be written or used: the failure domain of checkpoints, apart from
/// the bake's ([`BakeError::Checkpoint`] carries it).
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// Reading or writing the file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
    /// The file does not start with a checkpoint's magic and a known version.
    #[error("{path}: not a Radiant bake checkpoint (or another version)")]
    NotACheckpoint {
        /// The file.
        path: String,
    },
    /// The checksum does not match the contents.
    #[error("{path}: checksum mismatch: the file is damaged")]
    Damaged {
        /// The file.
        path: String,
    },
    /// The sizes in the header do not match the file's length, or the contents are
    /// inconsistent (rows out of order, sources outside the mesh, non-finite values).
    #[error("{path}: {what}")]
    Corrupt {
        /// The file.
        path: String,
        /// What does not hold.
        what: &'static str,
    },
    /// Written for other geometry or link parameters.
    #[error(
        "it was written for other geometry or bake parameters (fingerprint {found:016x}, this bake {expected:016x})"
    )]
    OtherScene {
        /// This bake's fingerprint.
        expected: u64,
        /// The file's.
        found: u64,
    },
    /// Its element hierarchy is not this mesh's.
    #[error(
        "its element hierarchy differs from this scene's ({found_elements} elements, {found_nodes} nodes; this scene {elements}, {nodes})"
    )]
    OtherMesh {
        /// This scene's elements.
        elements: usize,
        /// This scene's nodes.
        nodes: usize,
        /// The file's elements.
        found_elements: usize,
        /// The file's nodes.
        found_nodes: usize,
    },
    /// Written when nothing emitted: it holds no links to resume from.
    #[error("it was written when nothing emitted and holds no links")]
    NoLinks,
    /// A finished clustered result has no links to write (write from the `ClusterBake`).
    #[error("bakes of the clustered hierarchy have no checkpoints yet: use --hierarchy triangles")]
    ClusteredResult,
}

const MAGIC: &[u8; 15] = b"RADIANT-BAKE\0\0\0";
const VERSION: u8 = 2;
/// The version of clustered checkpoints.
const VERSION_CLUSTERED: u8 = 4;
/// The clustered version before exposure: an enclosed flag (u8) per element where version 4
/// has its exposed points; still read, an enclosed element as none exposed and any other as
/// all.
const VERSION_CLUSTERED_FLAGS: u8 = 3;

/// Whether a version holds a clustered hierarchy.
fn is_clustered(version: u8) -> bool {
    version == VERSION_CLUSTERED || version == VERSION_CLUSTERED_FLAGS
}

/// What a checkpoint restores.
pub struct Saved {
    /// The hierarchy's bookkeeping (its fingerprint, enclosed elements and oracle).
    pub hierarchy: Hierarchy,
    /// Node count of the mesh it was written for.
    pub nodes: usize,
    /// The links.
    pub links: Links,
    /// Radiosity per element.
    pub radiosity: Vec<Rgb>,
}

impl Saved {
    /// Refuses a checkpoint written for other geometry or link parameters.
    pub fn fits_scene(&self, fingerprint: u64) -> Result<(), BakeError> {
        if self.hierarchy.fingerprint != fingerprint {
            return Err(CheckpointError::OtherScene {
                expected: fingerprint,
                found: self.hierarchy.fingerprint,
            }
            .into());
        }
        Ok(())
    }

    /// Refuses a checkpoint whose element hierarchy is not `mesh`'s.
    pub fn fits_mesh(&self, mesh: &Mesh) -> Result<(), BakeError> {
        if self.hierarchy.dead.len() != mesh.element_count() || self.nodes != mesh.nodes.len() {
            return Err(CheckpointError::OtherMesh {
                elements: mesh.element_count(),
                nodes: mesh.nodes.len(),
                found_elements: self.hierarchy.dead.len(),
                found_nodes: self.nodes,
            }
            .into());
        }
        Ok(())
    }
}

/// Writes a checkpoint atomically (temporary file, fsync, rename).
pub fn write(
    path: &Path,
    hierarchy: &Hierarchy,
    nodes: usize,
    links: &Links,
    radiosity: &[Rgb],
) -> Result<(), BakeError> {
    let (fingerprint, dead) = (hierarchy.fingerprint, &hierarchy.dead);
    let n = radiosity.len();
    let hidden = links.hidden_known();
    let oracle = hierarchy.oracle.as_ref().filter(|o| o.bhat.len() == nodes);
    let flags = u64::from(hidden) | (u64::from(oracle.is_some()) << 1);
    write_atomically(path, |w| {
        w.write_all(MAGIC)?;
        w.write_all(&[VERSION])?;
        let hidden_count = if hidden { links.hidden_src.len() } else { 0 };
        for v in [
            fingerprint,
            n as u64,
            nodes as u64,
            links.len() as u64,
            hidden_count as u64,
            flags,
        ] {
            w.write_all(&v.to_le_bytes())?;
        }
        for &r in &links.row {
            w.write_all(&(r as u64).to_le_bytes())?;
        }
        for &s in &links.src {
            w.write_all(&s.to_le_bytes())?;
        }
        for &f in &links.ff {
            w.write_all(&f.to_le_bytes())?;
        }
        for &d in dead {
            w.write_all(&[u8::from(d)])?;
        }
        for b in radiosity {
            for c in b {
                w.write_all(&c.to_le_bytes())?;
            }
        }
        if hidden {
            for &r in &links.hidden_row {
                w.write_all(&(r as u64).to_le_bytes())?;
            }
            for &s in &links.hidden_src {
                w.write_all(&s.to_le_bytes())?;
            }
        }
        if let Some(o) = oracle {
            w.write_all(&o.eps.to_le_bytes())?;
            for b in &o.bhat {
                w.write_all(&b.to_le_bytes())?;
            }
        }
        Ok(())
    })
}

/// Reads little-endian values off a checked byte slice.
struct Cursor<'a> {
    data: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.data[self.at..self.at + N]);
        self.at += N;
        a
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
}

/// Reads and checks a checkpoint. Every size is checked against the file length before
/// anything is allocated, so a corrupt file is an error, not a crash.
pub fn read(path: &Path) -> Result<Saved, BakeError> {
    read_from(open(path)?, path)
}

/// [`read`] on a checkpoint's bytes held in memory; `path` names it in errors.
pub fn read_from(data: Vec<u8>, path: &Path) -> Result<Saved, BakeError> {
    let bad = |what: &'static str| corrupt(path, what);
    let (data, version) = checked(data, path, false, 32)?;
    let body = &data[..data.len() - 8];
    let mut c = Cursor { data: body, at: 16 };
    let header = if version == 1 { 32 } else { 48 };
    if body.len() < 16 + header {
        return Err(bad("sizes do not match the file length"));
    }
    let fingerprint = c.u64();
    let (n, nodes, nl) = (c.u64(), c.u64(), c.u64());
    let (nh, flags) = if version == 1 {
        (0, 0)
    } else {
        (c.u64(), c.u64())
    };
    let (hidden, has_oracle) = (flags & 1 != 0, flags & 2 != 0);
    let (n128, nl128, nh128) = (u128::from(n), u128::from(nl), u128::from(nh));
    let expected = 16
        + header as u128
        + (n128 + 1) * 8
        + nl128 * 8
        + n128
        + n128 * 24
        + if hidden {
            (n128 + 1) * 8 + nh128 * 4
        } else {
            0
        }
        + if has_oracle {
            8 + u128::from(nodes) * 8
        } else {
            0
        };
    if flags > 3 || (!hidden && nh != 0) || expected != body.len() as u128 {
        return Err(bad("sizes do not match the file length"));
    }
    let (n, nl, nh) = (n as usize, nl as usize, nh as usize);
    let row: Vec<usize> = (0..=n).map(|_| c.u64() as usize).collect();
    let src: Vec<u32> = (0..nl).map(|_| c.u32()).collect();
    let ff: Vec<f32> = (0..nl).map(|_| c.f32()).collect();
    let dead: Vec<bool> = (0..n).map(|_| c.take::<1>()[0] != 0).collect();
    let radiosity: Vec<Rgb> = (0..n).map(|_| [c.f64(), c.f64(), c.f64()]).collect();
    let (hidden_row, hidden_src) = if hidden {
        (
            (0..=n).map(|_| c.u64() as usize).collect(),
            (0..nh).map(|_| c.u32()).collect(),
        )
    } else {
        (Vec::new(), Vec::new())
    };
    let oracle = has_oracle.then(|| {
        let eps = c.f64();
        let bhat = (0..nodes).map(|_| c.f64()).collect();
        Estimates { bhat, eps }
    });
    // Structure: monotone rows ending at the link counts, sources inside the mesh, finite values.
    let rows_ok = |row: &[usize], count: usize| {
        row.first() == Some(&0)
            && row.last() == Some(&count)
            && row.windows(2).all(|w| w[0] <= w[1])
    };
    if !rows_ok(&row, nl)
        || (hidden && !rows_ok(&hidden_row, nh))
        || src.iter().chain(&hidden_src).any(|&s| s as u64 >= nodes)
        || ff.iter().any(|f| !f.is_finite() || *f < 0.0)
        || radiosity.iter().flatten().any(|b| !b.is_finite())
        || oracle.as_ref().is_some_and(|o| {
            !(o.eps.is_finite() && o.eps > 0.0) || o.bhat.iter().any(|x| !x.is_finite() || *x < 0.0)
        })
    {
        return Err(bad("inconsistent contents"));
    }
    Ok(Saved {
        hierarchy: Hierarchy {
            fingerprint,
            dead,
            oracle,
        },
        nodes: nodes as usize,
        links: Links {
            row,
            src,
            ff,
            hidden_row,
            hidden_src,
        },
        radiosity,
    })
}

/// Reads a checkpoint file: a regular file (a device or a pipe is refused, not read without
/// end).
fn open(path: &Path) -> Result<Vec<u8>, BakeError> {
    radiant_scene::read_regular_file(path, u64::MAX).map_err(|message| {
        CheckpointError::Io {
            path: path.display().to_string(),
            source: std::io::Error::other(message),
        }
        .into()
    })
}

/// Appends the checksum a checkpoint ends with to `body` (the magic, version and contents), as
/// [`write()`] does: a tool or a fuzzer that builds a checkpoint's bytes seals them with it.
pub fn seal(body: &mut Vec<u8>) {
    let mut h = Fnv::new();
    h.bytes(body);
    body.extend_from_slice(&h.0.to_le_bytes());
}

/// Checks a checkpoint of one hierarchy (`clustered`: version 3 or 4, else 1 or 2) with at least
/// `header` bytes after the magic, and its checksum; returns the bytes and the version.
/// The other hierarchy's file is [`BakeError::CheckpointHierarchy`].
fn checked(
    data: Vec<u8>,
    path: &Path,
    clustered: bool,
    header: usize,
) -> Result<(Vec<u8>, u8), BakeError> {
    let at = || path.display().to_string();
    let version = (data.len() >= 16 && &data[..15] == MAGIC).then(|| data[15]);
    let ours = |v: u8| is_clustered(v) == clustered;
    let known = |v: u8| matches!(v, 1 | 2) || is_clustered(v);
    match version {
        Some(v) if known(v) && !ours(v) => return Err(other_hierarchy(path, v)),
        Some(v) if known(v) && data.len() >= 16 + header + 8 => {}
        _ => return Err(CheckpointError::NotACheckpoint { path: at() }.into()),
    }
    let (body, sum) = data.split_at(data.len() - 8);
    let mut h = Fnv::new();
    h.bytes(body);
    if sum != h.0.to_le_bytes() {
        return Err(CheckpointError::Damaged { path: at() }.into());
    }
    let v = data[15];
    Ok((data, v))
}

fn corrupt(path: &Path, what: &'static str) -> BakeError {
    CheckpointError::Corrupt {
        path: path.display().to_string(),
        what,
    }
    .into()
}

fn other_hierarchy(path: &Path, version: u8) -> BakeError {
    let (found, needed) = if is_clustered(version) {
        ("clustered", "per-triangle")
    } else {
        ("per-triangle", "clustered")
    };
    BakeError::CheckpointHierarchy {
        path: path.display().to_string(),
        version,
        found,
        needed,
    }
}

/// What a clustered checkpoint holds.
#[derive(Clone, Debug, PartialEq)]
pub struct SavedClustered {
    /// The fingerprint of the geometry and parameters the links were built for.
    pub fingerprint: u64,
    /// The refinement threshold the links were built with (larger than asked when the memory
    /// budget coarsened the bake).
    pub refinement: f64,
    /// Nodes (mesh nodes and clusters).
    pub nodes: usize,
    /// The links.
    pub rows: Rows,
    /// Per element: its exposed probe points, of [`crate::exposure::POINTS`] (0: inside
    /// closed geometry).
    pub live: Vec<u8>,
    /// Radiosity per element.
    pub radiosity: Vec<Rgb>,
    /// The refinement's record, when the file holds it: the hash of the estimates it was
    /// refined with, its ops and sized subtrees.
    pub record: Option<(u64, Vec<u8>, Vec<Extent>)>,
}

/// Writes a clustered checkpoint atomically; `record`: the refinement's record (the hash of
/// its estimates, its ops and sized subtrees), for geometry edits after a resume.
pub fn write_clustered(
    path: &Path,
    fingerprint: u64,
    refinement: f64,
    rows: RowsRef,
    (live, radiosity): (&[u8], &[Rgb]),
    record: Option<(u64, &[u8], &[Extent])>,
) -> Result<(), BakeError> {
    let (n, nodes, nl) = (radiosity.len(), rows.row.len() - 1, rows.src.len());
    write_atomically(path, |w| {
        w.write_all(MAGIC)?;
        w.write_all(&[VERSION_CLUSTERED])?;
        for v in [
            fingerprint,
            n as u64,
            nodes as u64,
            nl as u64,
            refinement.to_bits(),
        ] {
            w.write_all(&v.to_le_bytes())?;
        }
        put(w, rows.row, |r| r.to_le_bytes())?;
        put(w, rows.src, |s| s.to_le_bytes())?;
        put(w, rows.ff, |f| f.to_le_bytes())?;
        w.write_all(live)?;
        put(w, radiosity.as_flattened(), |c| c.to_le_bytes())?;
        if let Some((hash, ops, sized)) = record {
            w.write_all(&hash.to_le_bytes())?;
            w.write_all(&(ops.len() as u64).to_le_bytes())?;
            w.write_all(&(sized.len() as u64).to_le_bytes())?;
            w.write_all(ops)?;
            for e in sized {
                for v in [e.ops, e.links, e.sized] {
                    w.write_all(&v.to_le_bytes())?;
                }
            }
        }
        Ok(())
    })
}

/// Reads and checks a clustered checkpoint (sizes before allocation, structure, finite
/// values); a per-triangle one is [`BakeError::CheckpointHierarchy`].
pub fn read_clustered(path: &Path) -> Result<SavedClustered, BakeError> {
    read_clustered_from(open(path)?, path)
}

/// [`read_clustered`] on a checkpoint's bytes held in memory; `path` names it in errors.
pub fn read_clustered_from(data: Vec<u8>, path: &Path) -> Result<SavedClustered, BakeError> {
    let bad = |what: &'static str| corrupt(path, what);
    let (data, version) = checked(data, path, true, 40)?;
    let body = &data[..data.len() - 8];
    let mut c = Cursor { data: body, at: 16 };
    let fingerprint = c.u64();
    let (n, nodes, nl) = (c.u64(), c.u64(), c.u64());
    let refinement = c.f64();
    let (n128, nodes128, nl128) = (u128::from(n), u128::from(nodes), u128::from(nl));
    let expected = 16 + 40 + (nodes128 + 1) * 8 + nl128 * 8 + n128 * 25;
    let len = body.len() as u128;
    if expected != len && expected + 24 > len {
        return Err(bad("sizes do not match the file length"));
    }
    let (n, nodes, nl) = (n as usize, nodes as usize, nl as usize);
    let row: Vec<u64> = (0..=nodes).map(|_| c.u64()).collect();
    let src: Vec<u32> = (0..nl).map(|_| c.u32()).collect();
    let ff: Vec<f32> = (0..nl).map(|_| c.f32()).collect();
    let live: Vec<u8> = (0..n).map(|_| c.take::<1>()[0]).collect();
    let live = if version == VERSION_CLUSTERED_FLAGS {
        let all = crate::exposure::POINTS as u8;
        live.iter().map(|&d| if d != 0 { 0 } else { all }).collect()
    } else {
        live
    };
    let radiosity: Vec<Rgb> = (0..n).map(|_| [c.f64(), c.f64(), c.f64()]).collect();
    let record = if expected == len {
        None
    } else {
        let (hash, no, nz) = (c.u64(), c.u64(), c.u64());
        if expected + 24 + u128::from(no) + u128::from(nz) * 24 != len {
            return Err(bad("sizes do not match the file length"));
        }
        let ops = c.data[c.at..c.at + no as usize].to_vec();
        c.at += no as usize;
        let sized: Vec<Extent> = (0..nz)
            .map(|_| Extent {
                ops: c.u64(),
                links: c.u64(),
                sized: c.u64(),
            })
            .collect();
        Some((hash, ops, sized))
    };
    let header_ok = row.first() == Some(&0)
        && row.last() == Some(&(nl as u64))
        && row.windows(2).all(|w| w[0] <= w[1])
        && refinement.is_finite()
        && refinement > 0.0;
    if !header_ok
        || src.iter().any(|&s| s as usize >= nodes)
        || live
            .iter()
            .any(|&l| usize::from(l) > crate::exposure::POINTS)
        || ff.iter().any(|f| !f.is_finite() || *f < 0.0)
        || radiosity.iter().flatten().any(|b| !b.is_finite())
    {
        return Err(bad("inconsistent contents"));
    }
    Ok(SavedClustered {
        fingerprint,
        refinement,
        nodes,
        rows: Rows { row, src, ff },
        live,
        radiosity,
        record,
    })
}

/// Writes numbers little-endian: in one piece where that is how they lie in memory (a
/// level's checkpoint holds 18 M links), else one by one.
fn put<T: bytemuck::Pod, const N: usize>(
    w: &mut dyn Write,
    v: &[T],
    le: impl Fn(&T) -> [u8; N],
) -> std::io::Result<()> {
    if cfg!(target_endian = "little") {
        w.write_all(bytemuck::cast_slice(v))
    } else {
        v.iter().try_for_each(|x| w.write_all(&le(x)))
    }
}

/// A writer that hashes what goes through it: the checkpoint's trailing checksum.
struct Hashing<W: Write> {
    inner: W,
    hash: Fnv,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(b)?;
        self.hash.bytes(&b[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Writes what `body` writes, and its checksum, to a temporary file beside `path`, syncs it
/// and renames it to `path`, so that a crash leaves the old checkpoint or the new one, never
/// half of one (the temporary file is removed when writing fails). Streamed through a small
/// buffer: Sponza's checkpoint with its record is 446 MB, which was first built in memory
/// (fresh pages, dear on the virtual machine of ARCHITECTURE.md's figures) and then hashed
/// and written, 9.1 s in all.
fn write_atomically(
    path: &Path,
    body: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<(), BakeError> {
    let io = |source: std::io::Error| CheckpointError::Io {
        path: path.display().to_string(),
        source,
    };
    // A rename would put the checkpoint in place of a device or a directory (as root, of
    // /dev/zero itself).
    if std::fs::metadata(path).is_ok_and(|m| !m.is_file()) {
        return Err(io(std::io::Error::other(
            "not a regular file: a checkpoint is written only to a file or a new path",
        ))
        .into());
    }
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n_tmp = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let name = path
        .file_name()
        .map_or_else(|| "checkpoint".into(), |n| n.to_string_lossy().into_owned());
    let tmp = path.with_file_name(format!(".{name}.tmp.{}.{n_tmp}", std::process::id()));
    let written = (|| {
        let file = std::fs::File::create(&tmp)?;
        let mut w = Hashing {
            inner: std::io::BufWriter::with_capacity(1 << 20, file),
            hash: Fnv::new(),
        };
        body(&mut w)?;
        let mut out = w.inner;
        out.write_all(&w.hash.0.to_le_bytes())?;
        out.into_inner().map_err(|e| e.into_error())?.sync_all()
    })();
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(io(e).into());
    }
    std::fs::rename(&tmp, path).map_err(io)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_write_is_whole_with_its_checksum_or_leaves_the_old_file_and_no_temporary() {
        let dir = std::env::temp_dir().join(format!("radiant-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let path = dir.join("c.ckpt");
        write_atomically(&path, |w: &mut dyn Write| w.write_all(b"first")).expect("writes");
        let first = std::fs::read(&path).expect("written");
        let mut h = Fnv::new();
        h.bytes(b"first");
        assert_eq!(first[..5], *b"first");
        assert_eq!(first[5..], h.0.to_le_bytes());
        // Streamed through the buffer in pieces larger and smaller than it, the same bytes.
        let big: Vec<u8> = (0..3_000_000u32).map(|i| (i % 251) as u8).collect();
        write_atomically(&path, |w: &mut dyn Write| {
            w.write_all(&big[..10])?;
            w.write_all(&big[10..])
        })
        .expect("writes");
        let mut h = Fnv::new();
        h.bytes(&big);
        let again = std::fs::read(&path).expect("written");
        assert_eq!(
            (&again[..big.len()], &again[big.len()..]),
            (&big[..], &h.0.to_le_bytes()[..])
        );
        write_atomically(&path, |w: &mut dyn Write| w.write_all(b"first")).expect("writes");
        let failed = write_atomically(&path, |w: &mut dyn Write| {
            w.write_all(b"second")?;
            Err(std::io::Error::other("the disk is full"))
        });
        assert!(matches!(
            failed,
            Err(BakeError::Checkpoint(CheckpointError::Io { .. }))
        ));
        assert_eq!(std::fs::read(&path).expect("kept"), first);
        let files = std::fs::read_dir(&dir).expect("dir").count();
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(files, 1, "a temporary file was left");
    }

    /// A version-1 file (no fully occluded links, no oracle) is still read.
    #[test]
    fn reads_version_1() {
        let mut buf = Vec::new();
        buf.extend_from_slice(MAGIC);
        buf.push(1);
        // Fingerprint, one element, one node, one link.
        for v in [42u64, 1, 1, 1] {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        for r in [0u64, 1] {
            buf.extend_from_slice(&r.to_le_bytes());
        }
        buf.extend_from_slice(&0u32.to_le_bytes());
        buf.extend_from_slice(&0.5f32.to_le_bytes());
        buf.push(0);
        for c in [1.0f64, 2.0, 3.0] {
            buf.extend_from_slice(&c.to_le_bytes());
        }
        let mut h = Fnv::new();
        h.bytes(&buf);
        buf.extend_from_slice(&h.0.to_le_bytes());
        let path = std::env::temp_dir().join(format!("radiant-v1-{}.ckpt", std::process::id()));
        std::fs::write(&path, &buf).expect("write");
        let saved = read(&path).expect("a version-1 checkpoint");
        let _ = std::fs::remove_file(&path);
        assert_eq!(saved.hierarchy.fingerprint, 42);
        assert_eq!(saved.links.src, [0]);
        assert_eq!(saved.links.ff, [0.5]);
        assert!(!saved.links.hidden_known());
        assert!(saved.hierarchy.oracle.is_none());
        assert_eq!(saved.radiosity, [[1.0, 2.0, 3.0]]);
    }

    /// Version 2 keeps the fully occluded links and the oracle.
    #[test]
    fn version_2_round_trips() {
        let links = Links {
            row: vec![0, 1, 1],
            src: vec![2],
            ff: vec![0.25],
            hidden_row: vec![0, 0, 2],
            hidden_src: vec![0, 1],
        };
        let path = std::env::temp_dir().join(format!("radiant-v2-{}.ckpt", std::process::id()));
        let bhat = [0.5, 0.7, 0.9];
        let hierarchy = Hierarchy {
            fingerprint: 7,
            dead: vec![false, true],
            oracle: Some(Estimates {
                bhat: bhat.to_vec(),
                eps: 0.02,
            }),
        };
        write(&path, &hierarchy, 3, &links, &[[0.1; 3], [0.2; 3]]).expect("write");
        let saved = read(&path).expect("read");
        let _ = std::fs::remove_file(&path);
        assert_eq!(saved.links.hidden_row, links.hidden_row);
        assert_eq!(saved.links.hidden_src, links.hidden_src);
        assert_eq!(saved.hierarchy, hierarchy);
    }

    #[test]
    fn a_clustered_checkpoint_keeps_exposure_and_version_3_flags_are_still_read() {
        let path = std::env::temp_dir().join(format!("radiant-v4-{}.ckpt", std::process::id()));
        let rows = Rows {
            row: vec![0, 1, 1, 1],
            src: vec![2],
            ff: vec![0.25],
        };
        let live = [0u8, 4, 9];
        let b = [[0.1; 3], [0.2; 3], [0.3; 3]];
        let write = |live: &[u8]| {
            let rr = RowsRef {
                row: &rows.row,
                src: &rows.src,
                ff: &rows.ff,
            };
            write_clustered(&path, 7, 0.02, rr, (live, &b), None).expect("write")
        };
        write(&live);
        let saved = read_clustered(&path).expect("read");
        assert_eq!(saved.live, live);
        assert_eq!((saved.rows, saved.radiosity), (rows.clone(), b.to_vec()));
        // The same file as version 3 wrote it: enclosed flags where the exposure is.
        let mut data = std::fs::read(&path).expect("written");
        let at = 16 + 40 + 4 * 8 + 4 + 4;
        data[15] = VERSION_CLUSTERED_FLAGS;
        data[at..at + 3].copy_from_slice(&[1, 0, 0]);
        data.truncate(data.len() - 8);
        seal(&mut data);
        std::fs::write(&path, &data).expect("rewritten");
        let old = read_clustered(&path).expect("a version-3 file is read");
        assert_eq!(old.live, [0, 9, 9]);
        // More exposed points than there are is a corrupt file.
        write(&[0, 4, 10]);
        let bad = read_clustered(&path);
        let _ = std::fs::remove_file(&path);
        assert!(
            matches!(
                bad,
                Err(BakeError::Checkpoint(CheckpointError::Corrupt { .. }))
            ),
            "{bad:?}"
        );
    }

    #[test]
    fn bytes_read_as_the_file_and_a_device_is_neither_read_nor_replaced() {
        let path = std::env::temp_dir().join(format!("radiant-bytes-{}.ckpt", std::process::id()));
        let rows = Rows {
            row: vec![0, 1, 1],
            src: vec![1],
            ff: vec![0.5],
        };
        let rr = RowsRef {
            row: &rows.row,
            src: &rows.src,
            ff: &rows.ff,
        };
        let b = [[0.1; 3], [0.2; 3]];
        write_clustered(&path, 7, 0.02, rr, (&[9, 9], &b), None).expect("write");
        let mut data = std::fs::read(&path).expect("written");
        let from_file = read_clustered(&path).expect("read");
        let _ = std::fs::remove_file(&path);
        assert_eq!(
            read_clustered_from(data.clone(), &path).expect("bytes"),
            from_file
        );
        // Sealing the body again gives the same checksum; a flipped byte fails it.
        data.truncate(data.len() - 8);
        let mut sealed = data.clone();
        seal(&mut sealed);
        assert_eq!(
            read_clustered_from(sealed.clone(), &path).expect("sealed"),
            from_file
        );
        sealed[20] ^= 1;
        assert!(matches!(
            read_clustered_from(sealed, &path),
            Err(BakeError::Checkpoint(CheckpointError::Damaged { .. }))
        ));
        // A device is refused unread, and never replaced by a write.
        for device in ["/dev/zero", "/dev/urandom"] {
            let device = Path::new(device);
            assert!(matches!(
                read_clustered(device),
                Err(BakeError::Checkpoint(CheckpointError::Io { .. }))
            ));
            assert!(matches!(
                read(device),
                Err(BakeError::Checkpoint(CheckpointError::Io { .. }))
            ));
        }
        let dir = std::env::temp_dir().join(format!("radiant-ckdir-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let wrote = write_clustered(&dir, 7, 0.02, rr, (&[9, 9], &b), None);
        assert!(
            matches!(&wrote, Err(BakeError::Checkpoint(CheckpointError::Io { source, .. }))
                if source.to_string().contains("not a regular file")),
            "{wrote:?}"
        );
        assert!(dir.is_dir());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
