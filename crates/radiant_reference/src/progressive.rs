//! Progressive estimation: rounds of independent sample chunks, in parallel, until a sample
//! count, a target standard error or a time limit is reached.
//!
//! Sample `k` of item `i` always comes from chunk `k / chunk` of item `i`, whose random stream
//! depends only on the seed and those indices; chunks are summed in index order. So a given
//! sample count gives bit-identical results on any number of threads.

use std::time::Instant;

use rayon::prelude::*;

use crate::rng::Rng;
use crate::{Estimate, Params, Progress, ReferenceError, Run, Stopped};

/// Running sums of one item's samples (per channel: Σx, Σx²).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Sum {
    n: u64,
    s: [f64; 3],
    s2: [f64; 3],
}

impl Sum {
    fn add(&mut self, v: [f64; 3]) {
        self.n += 1;
        for c in 0..3 {
            self.s[c] += v[c];
            self.s2[c] += v[c] * v[c];
        }
    }

    fn merge(&mut self, o: &Sum) {
        self.n += o.n;
        for c in 0..3 {
            self.s[c] += o.s[c];
            self.s2[c] += o.s2[c];
        }
    }

    /// The mean and its standard error (sample variance / n).
    pub(crate) fn estimate(&self) -> Estimate {
        if self.n == 0 {
            return Estimate::default();
        }
        let n = self.n as f64;
        let mean = self.s.map(|s| s / n);
        let se = [0, 1, 2].map(|c| {
            if self.n < 2 {
                return f64::INFINITY;
            }
            let var = ((self.s2[c] - self.s[c] * mean[c]) / (n - 1.0)).max(0.0);
            (var / n).sqrt()
        });
        Estimate {
            mean,
            se,
            samples: self.n,
        }
    }
}

/// When items stop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Rule {
    /// Each item until its own relative standard error meets the target (surfaces, points).
    PerItem,
    /// All items alike until `Σ se / Σ mean` over all of them meets it (an image's pixels).
    Aggregate,
}

/// What one estimation needs.
pub(crate) struct Job<'a, F> {
    pub(crate) items: usize,
    /// A stream id, so surfaces, points and pixels never share random numbers.
    pub(crate) kind: u64,
    /// Samples per chunk.
    pub(crate) chunk: u64,
    pub(crate) rule: Rule,
    /// Chunks an item needs before the target may stop it: a dark item whose first few
    /// hundred paths all found nothing has a standard error of zero that means nothing.
    pub(crate) min_chunks: u64,
    pub(crate) what: &'static str,
    /// One sample of item `i`: the value, adding the rays it cast to the counter.
    pub(crate) sample: F,
    pub(crate) progress: &'a (dyn Fn(&Progress) + Sync),
}

/// The median of the estimates' `‖mean‖` (0 for none, or where it is not finite).
fn median_magnitude(estimates: &[Estimate]) -> f64 {
    let mut m: Vec<f64> = estimates.iter().map(Estimate::magnitude).collect();
    if m.is_empty() {
        return 0.0;
    }
    let k = m.len() / 2;
    let (_, mid, _) = m.select_nth_unstable_by(k, f64::total_cmp);
    if mid.is_finite() { *mid } else { 0.0 }
}

fn aggregate_rel(sums: &[Sum]) -> f64 {
    let (mut se, mut mean) = (0.0, 0.0);
    for s in sums {
        let e = s.estimate();
        for c in 0..3 {
            se += e.se[c];
            mean += e.mean[c].abs();
        }
    }
    if se == 0.0 {
        0.0
    } else if mean > 0.0 {
        se / mean
    } else {
        f64::INFINITY
    }
}

pub(crate) fn run<F>(
    params: &Params,
    job: Job<'_, F>,
) -> Result<(Vec<Estimate>, Run), ReferenceError>
where
    F: Fn(usize, &mut Rng, &mut u64) -> [f64; 3] + Sync,
{
    params.validate()?;
    let start = Instant::now();
    let deadline = params.time_limit.map(|t| start + t);
    let n = job.items;
    let max_chunks = params.samples.map(|s| s.div_ceil(job.chunk));
    let mut sums = vec![Sum::default(); n];
    let mut next = vec![0u64; n];
    let mut active = vec![true; n];
    let mut rays_total = 0u64;
    let mut per_round = 1u64;
    let mut rel = f64::INFINITY;
    let stopped = loop {
        let mut work = Vec::new();
        for i in (0..n).filter(|&i| active[i]) {
            let end = max_chunks.map_or(next[i] + per_round, |m| m.min(next[i] + per_round));
            work.extend((next[i]..end).map(|c| (i, c)));
        }
        if work.is_empty() {
            break Stopped::Samples;
        }
        let round = Instant::now();
        let results: Vec<Option<(Sum, u64, bool)>> = work
            .par_iter()
            .map(|&(i, c)| {
                if deadline.is_some_and(|d| Instant::now() >= d) {
                    return None;
                }
                let count = match params.samples {
                    Some(total) => job.chunk.min(total - c * job.chunk),
                    None => job.chunk,
                };
                let mut rng = Rng::for_chunk(params.seed, job.kind, i as u64, c);
                let (mut sum, mut rays, mut finite) = (Sum::default(), 0u64, true);
                for _ in 0..count {
                    let v = (job.sample)(i, &mut rng, &mut rays);
                    finite &= v.iter().all(|x| x.is_finite());
                    sum.add(v);
                }
                Some((sum, rays, finite))
            })
            .collect();
        let mut ran = 0usize;
        for (&(i, c), r) in work.iter().zip(&results) {
            if let Some((s, rays, finite)) = r {
                if !finite {
                    return Err(ReferenceError::NonFinite {
                        what: job.what,
                        item: i,
                    });
                }
                sums[i].merge(s);
                next[i] = c + 1;
                rays_total += rays;
                ran += 1;
            }
        }
        let elapsed = start.elapsed().as_secs_f64();
        // Which items go on, and how far from the target the worst one is.
        let target = params.target_error;
        let mut remaining_chunks = 0.0;
        match job.rule {
            Rule::PerItem => {
                rel = 0.0;
                // An item far darker than most is held to an absolute error, not its own
                // relative one (which a surface near zero never reaches): see `DARK`.
                let estimates: Vec<Estimate> = sums.iter().map(Sum::estimate).collect();
                let floor = crate::DARK * median_magnitude(&estimates);
                for i in 0..n {
                    let r = estimates[i].rel_error_above(floor);
                    rel = rel.max(r);
                    if let Some(t) = target {
                        active[i] = active[i] && (r > t || next[i] < job.min_chunks);
                        if active[i] {
                            let f = if r.is_finite() {
                                (r / t).powi(2) - 1.0
                            } else {
                                1.0
                            };
                            remaining_chunks += next[i] as f64 * f.max(0.0);
                        }
                    }
                    if max_chunks.is_some_and(|m| next[i] >= m) {
                        active[i] = false;
                    }
                }
            }
            Rule::Aggregate => {
                rel = aggregate_rel(&sums);
                let reached = target.is_some_and(|t| rel <= t);
                let exhausted = max_chunks.is_some_and(|m| next.iter().all(|&c| c >= m));
                if let Some(t) = target
                    && rel.is_finite()
                {
                    remaining_chunks =
                        next.iter().sum::<u64>() as f64 * ((rel / t).powi(2) - 1.0).max(0.0);
                }
                if reached || exhausted {
                    active.fill(false);
                }
            }
        }
        let done: u64 = next.iter().sum();
        // How far along: the first stopping rule to be met decides.
        let mut fraction: f64 = 0.0;
        if let Some(m) = max_chunks {
            fraction = fraction.max(done as f64 / (m as f64 * n as f64));
        }
        if target.is_some() {
            fraction = fraction.max(done as f64 / (done as f64 + remaining_chunks).max(1.0));
        }
        if let Some(t) = params.time_limit {
            fraction = fraction.max(elapsed / t.as_secs_f64().max(1e-9));
        }
        let fraction = fraction.clamp(0.0, 1.0);
        let paths: u64 = sums.iter().map(|s| s.n).sum();
        (job.progress)(&Progress {
            what: job.what,
            paths,
            seconds: elapsed,
            rel_error: rel,
            fraction,
            eta_seconds: (fraction > 0.0).then(|| elapsed * (1.0 - fraction) / fraction),
        });
        tracing::info!(
            what = job.what,
            paths,
            seconds = elapsed,
            rel_error = rel,
            "reference progress"
        );
        if deadline.is_some_and(|d| Instant::now() >= d) {
            break Stopped::TimeLimit;
        }
        if !active.iter().any(|&a| a) {
            let exhausted = max_chunks.is_some_and(|m| next.iter().all(|&c| c >= m));
            break if target.is_some_and(|t| rel <= t) || !exhausted {
                Stopped::Target
            } else {
                Stopped::Samples
            };
        }
        // The next round: about twice as many chunks per item, but rounds of about a second
        // (or a quarter of the time so far) so that progress and the time limit stay close.
        let per_chunk = round.elapsed().as_secs_f64() / ran.max(1) as f64;
        let live = active.iter().filter(|&&a| a).count().max(1) as f64;
        let budget = (0.25 * elapsed).max(1.0);
        let by_time = (budget / (per_chunk * live).max(1e-12)).floor() as u64;
        per_round = (2 * per_round).min(by_time.max(1)).max(1);
    };
    let estimates: Vec<Estimate> = sums.iter().map(Sum::estimate).collect();
    let run = Run {
        paths: sums.iter().map(|s| s.n).sum(),
        rays: rays_total,
        seconds: start.elapsed().as_secs_f64(),
        threads: rayon::current_num_threads(),
        stopped,
        rel_error: rel,
    };
    Ok((estimates, run))
}
