//! Bake checkpoints: the links (form factors), the enclosed-element flags and the solution,
//! written atomically, so a long bake resumes after a restart without recomputing form factors.
//!
//! Layout, little-endian: 16-byte magic and version; the fingerprint of the geometry, lights and
//! every parameter the links depend on; element, node and link counts; row offsets (u64),
//! sources (u32), form factors (f32), enclosed flags (u8), radiosity (3 × f64 per element);
//! an FNV-1a checksum of all of it. Materials and lights are not in the fingerprint: a
//! checkpoint of the same geometry with other colours or lights resumes as an edit would.

use std::io::Write;
use std::path::Path;

use radiant_scene::Scene;

use crate::BakeError;
use crate::bake::BakeParams;
use crate::links::Links;
use crate::system::Rgb;

const MAGIC: &[u8; 16] = b"RADIANT-BAKE\0\0\0\x01";

/// What a checkpoint restores.
pub struct Saved {
    /// The fingerprint it was written for.
    pub fingerprint: u64,
    /// Node count of the mesh it was written for.
    pub nodes: usize,
    /// The links.
    pub links: Links,
    /// Enclosed elements.
    pub dead: Vec<bool>,
    /// Radiosity per element.
    pub radiosity: Vec<Rgb>,
}

/// FNV-1a, 64 bit.
#[derive(Clone, Copy)]
struct Fnv(u64);

impl Fnv {
    fn new() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
    fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= u64::from(x);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    fn f64(&mut self, x: f64) {
        self.bytes(&x.to_bits().to_le_bytes());
    }
}

/// The fingerprint of what links depend on: geometry and the mesh, link and form-factor
/// parameters. Lights and materials are not in it: resuming computes direct light again and
/// takes the scene's materials, as edits do.
pub fn fingerprint(scene: &Scene, params: &BakeParams) -> u64 {
    let mut h = Fnv::new();
    h.bytes(
        format!(
            "{:?}|{:?}|{:?}|{:?}",
            params.mesh, params.links, params.form_factors, params.ff
        )
        .as_bytes(),
    );
    for t in &scene.triangles {
        for v in t.vertices {
            h.f64(v.x);
            h.f64(v.y);
            h.f64(v.z);
        }
        h.bytes(&t.surface.to_le_bytes());
    }
    h.0
}

/// Writes a checkpoint atomically (temporary file, fsync, rename).
pub fn write(
    path: &Path,
    fingerprint: u64,
    nodes: usize,
    links: &Links,
    dead: &[bool],
    radiosity: &[Rgb],
) -> Result<(), BakeError> {
    let io = |e: std::io::Error| BakeError::Checkpoint(format!("{}: {e}", path.display()));
    let n = radiosity.len();
    let mut buf: Vec<u8> = Vec::with_capacity(64 + links.bytes() + n * 25);
    buf.extend_from_slice(MAGIC);
    for v in [fingerprint, n as u64, nodes as u64, links.len() as u64] {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    for &r in &links.row {
        buf.extend_from_slice(&(r as u64).to_le_bytes());
    }
    for &s in &links.src {
        buf.extend_from_slice(&s.to_le_bytes());
    }
    for &f in &links.ff {
        buf.extend_from_slice(&f.to_le_bytes());
    }
    buf.extend(dead.iter().map(|&d| u8::from(d)));
    for b in radiosity {
        for c in b {
            buf.extend_from_slice(&c.to_le_bytes());
        }
    }
    let mut h = Fnv::new();
    h.bytes(&buf);
    buf.extend_from_slice(&h.0.to_le_bytes());
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n_tmp = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let name = path
        .file_name()
        .map_or_else(|| "checkpoint".into(), |n| n.to_string_lossy().into_owned());
    let tmp = path.with_file_name(format!(".{name}.tmp.{}.{n_tmp}", std::process::id()));
    {
        let mut f = std::fs::File::create(&tmp).map_err(io)?;
        f.write_all(&buf).map_err(io)?;
        f.sync_all().map_err(io)?;
    }
    std::fs::rename(&tmp, path).map_err(io)?;
    Ok(())
}

/// Reads and checks a checkpoint. Every size is checked against the file length before
/// anything is allocated, so a corrupt file is an error, not a crash.
pub fn read(path: &Path) -> Result<Saved, BakeError> {
    let bad = |what: &str| BakeError::Checkpoint(format!("{}: {what}", path.display()));
    let data = std::fs::read(path).map_err(|e| bad(&e.to_string()))?;
    if data.len() < 16 + 32 + 8 || &data[..16] != MAGIC {
        return Err(bad("not a Radiant bake checkpoint (or another version)"));
    }
    let (body, sum) = data.split_at(data.len() - 8);
    let mut h = Fnv::new();
    h.bytes(body);
    if sum != h.0.to_le_bytes() {
        return Err(bad("checksum mismatch: the file is damaged"));
    }
    let u64_at = |o: usize| {
        let mut a = [0u8; 8];
        a.copy_from_slice(&body[o..o + 8]);
        u64::from_le_bytes(a)
    };
    let fingerprint = u64_at(16);
    let (n, nodes, nl) = (u64_at(24), u64_at(32), u64_at(40));
    let expected =
        48u128 + (u128::from(n) + 1) * 8 + u128::from(nl) * 8 + u128::from(n) + u128::from(n) * 24;
    if expected != body.len() as u128 {
        return Err(bad("sizes do not match the file length"));
    }
    let (n, nl) = (n as usize, nl as usize);
    let mut o = 48;
    let mut row = Vec::with_capacity(n + 1);
    for _ in 0..=n {
        row.push(u64_at(o) as usize);
        o += 8;
    }
    let mut src = Vec::with_capacity(nl);
    for k in 0..nl {
        let b = &body[o + 4 * k..o + 4 * k + 4];
        src.push(u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    }
    o += 4 * nl;
    let mut ff = Vec::with_capacity(nl);
    for k in 0..nl {
        let b = &body[o + 4 * k..o + 4 * k + 4];
        ff.push(f32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    }
    o += 4 * nl;
    let dead = body[o..o + n].iter().map(|&d| d != 0).collect();
    o += n;
    let mut radiosity = Vec::with_capacity(n);
    for i in 0..n {
        let at = |c: usize| {
            let mut a = [0u8; 8];
            a.copy_from_slice(&body[o + 24 * i + 8 * c..o + 24 * i + 8 * c + 8]);
            f64::from_le_bytes(a)
        };
        radiosity.push([at(0), at(1), at(2)]);
    }
    // Structure: monotone rows ending at the link count, sources inside the mesh, finite values.
    if row.first() != Some(&0)
        || row.last() != Some(&nl)
        || row.windows(2).any(|w| w[0] > w[1])
        || src.iter().any(|&s| s as u64 >= nodes)
        || ff.iter().any(|f| !f.is_finite() || *f < 0.0)
        || radiosity.iter().flatten().any(|b| !b.is_finite())
    {
        return Err(bad("inconsistent contents"));
    }
    Ok(Saved {
        fingerprint,
        nodes: nodes as usize,
        links: Links { row, src, ff },
        dead,
        radiosity,
    })
}
