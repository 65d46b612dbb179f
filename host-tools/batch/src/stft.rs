//! The STFT of many channels at once: [`StftPlan::step`] for every lane of a chunk, with the
//! lanes innermost so that one twiddle meets every lane ([`crate::kernels::stft_bin_sums`]).

use slipguard_core::features::stft::{MAX_WINDOW, StftPlan, StftState};

use crate::kernels::stft_bin_sums;

/// Working buffers of [`step_lanes`] for up to `lanes` lanes.
#[derive(Clone, Debug)]
pub struct StftLanes {
    /// Windowed samples, oldest first, Q2.30: `xw[n·lanes + i]`.
    xw: Vec<i32>,
    /// One bin's accumulators per lane, Q3.45.
    re: Vec<i64>,
    im: Vec<i64>,
    lanes: usize,
}

impl StftLanes {
    /// Buffers for up to `lanes` lanes.
    pub fn new(lanes: usize) -> Self {
        Self {
            xw: vec![0; MAX_WINDOW * lanes],
            re: vec![0; lanes],
            im: vec![0; lanes],
            lanes,
        }
    }
}

/// [`StftPlan::step`] of many channels at once: lane i with `on[i]` pushes `x[i]` into
/// `states[i]`, and bin b's magnitude goes to `out[b·n + i]` (n = `on.len()`, at most the
/// buffers' lanes); lanes not `on` keep their state and get 0. The same numbers as
/// [`StftPlan::step`]: the same windowed samples ([`StftPlan::push_windowed`]), per bin the
/// same exact i64 sums (|sum| < 2^51) in another order, then the same
/// [`StftPlan::magnitude`].
pub fn step_lanes(
    plan: &StftPlan,
    buf: &mut StftLanes,
    states: &mut [StftState],
    x: &[i16],
    on: &[bool],
    out: &mut [i16],
) {
    let config = plan.config();
    let lanes = on.len().min(buf.lanes).min(states.len()).min(x.len());
    let n = usize::from(config.window_len);
    let bins = usize::from(config.n_bins);
    let xw = &mut buf.xw[..n * lanes];
    let mut one = [0i32; MAX_WINDOW];
    for i in 0..lanes {
        if on[i] {
            plan.push_windowed(&mut states[i], x[i], &mut one);
        } else {
            one = [0; MAX_WINDOW];
        }
        for (k, &v) in one.iter().take(n).enumerate() {
            xw[k * lanes + i] = v;
        }
    }
    for (b, k) in (usize::from(config.first_bin)..).take(bins).enumerate() {
        let (re, im) = (&mut buf.re[..lanes], &mut buf.im[..lanes]);
        re.fill(0);
        im.fill(0);
        for t in 0..n {
            let (c, s) = plan.twiddle(k, t);
            stft_bin_sums(&xw[t * lanes..(t + 1) * lanes], c, s, re, im);
        }
        if let Some(o) = out.get_mut(b * lanes..(b + 1) * lanes) {
            for i in 0..lanes {
                o[i] = if on[i] {
                    plan.magnitude(re[i], im[i])
                } else {
                    0
                };
            }
        }
    }
}
