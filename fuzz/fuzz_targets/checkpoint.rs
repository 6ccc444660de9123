//! Checkpoints of both hierarchies: the input is a checkpoint's magic, version and contents, to
//! which the harness appends a valid checksum (else nearly every input would stop at the
//! checksum), then read by the per-triangle and the clustered reader. Both must answer with
//! their typed errors; what reads must hold finite values.
#![no_main]

use std::path::Path;

use radiant_radiosity::checkpoint;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.ckpt");
    let mut sealed = data.to_vec();
    checkpoint::seal(&mut sealed);
    if let Ok(saved) = checkpoint::read_from(sealed.clone(), path) {
        assert!(saved.radiosity.iter().flatten().all(|b| b.is_finite()));
    }
    if let Ok(saved) = checkpoint::read_clustered_from(sealed, path) {
        assert!(saved.radiosity.iter().flatten().all(|b| b.is_finite()));
    }
    // Unsealed, the checksum must catch what a flipped byte did.
    let _ = checkpoint::read_clustered_from(data.to_vec(), path);
});
