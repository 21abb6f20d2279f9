//! Validation of `[v2x]`: the step, the GNSS process, the matcher, the
//! trackers, the CPM generation rules, the channel and the receivers'
//! association.

use super::ConfigError;
use super::check::{Checker, field, num};
use super::raw::{RawChannel, RawCpm, RawTracker, RawV2x};
use crate::matching::Method;
use crate::v2x::V2xSettings;
use crate::v2x::channel::{ChannelSettings, LossKind, LossModel};
use crate::v2x::cpm::CpmSettings;
use crate::v2x::receiver::AssociationSettings;
use crate::v2x::tracker::TrackerSettings;

/// Objects per message at most (a CPM's object container is bounded).
const MAX_CPM_OBJECTS: usize = 1000;

pub(super) fn v2x(c: &Checker, v: RawV2x) -> Result<V2xSettings, ConfigError> {
    if !(v.step_length_s > 0.0 && v.step_length_s <= 1.0) {
        return Err(c.invalid(
            "v2x.step_length_s",
            format!("must be in (0, 1] s, got {}", num(v.step_length_s)),
        ));
    }
    c.within(field!("v2x", v.gnss_correlation_s), 0.0, 1e6)?;
    c.within(
        field!("v2x", v.gnss_heading_speed_sigma_mps),
        0.0,
        super::check::MAX_SPEED_SIGMA_MPS,
    )?;
    if matches!(v.matcher, Method::Oracle | Method::External) {
        return Err(c.invalid("v2x.matcher", "must be a matching method".into()));
    }
    let a = v.association;
    if !(a.smoothing > 0.0 && a.smoothing <= 1.0) {
        return Err(c.invalid(
            "v2x.association.smoothing",
            format!("must be in (0, 1], got {}", num(a.smoothing)),
        ));
    }
    if !(0.0..1.0).contains(&a.threshold) {
        return Err(c.invalid(
            "v2x.association.threshold",
            format!("must be in [0, 1), got {}", num(a.threshold)),
        ));
    }
    c.fraction(field!("v2x.association", a.pose_smoothing))?;
    let tracker = tracker(c, v.tracker)?;
    if tracker.max_coast_s + 1e-9 < v.step_length_s {
        let (key, other) = c.blame("v2x.tracker.max_coast_s", "v2x.step_length_s");
        return Err(c.invalid(
            key,
            format!(
                "a track not updated for {} s is dropped, but steps are {} s apart: every \
                 track would be dropped before its second hit (the coasting gap must be at \
                 least one step; see {other})",
                num(tracker.max_coast_s),
                num(v.step_length_s)
            ),
        ));
    }
    Ok(V2xSettings {
        mode: v.mode,
        step_length_s: v.step_length_s,
        gnss_correlation_s: v.gnss_correlation_s,
        gnss_heading_speed_sigma_mps: v.gnss_heading_speed_sigma_mps,
        matcher: v.matcher,
        pose_noise: v.pose_noise,
        compensate_latency: v.compensate_latency,
        association: AssociationSettings {
            smoothing: a.smoothing,
            threshold: a.threshold,
            pose_smoothing: a.pose_smoothing,
        },
        tracker,
        cpm: cpm(c, v.cpm)?,
        channel: channel(c, v.channel)?,
    })
}

fn tracker(c: &Checker, t: RawTracker) -> Result<TrackerSettings, ConfigError> {
    c.positive(field!("v2x.tracker", t.accel_sigma_mps2))?;
    c.positive(field!("v2x.tracker", t.gate_chi2))?;
    c.positive(field!("v2x.tracker", t.max_coast_s))?;
    c.positive(field!("v2x.tracker", t.birth_speed_sigma_mps))?;
    c.non_negative(field!("v2x.tracker", t.appearance_sigma))?;
    c.non_negative(field!("v2x.tracker", t.reid_s))?;
    if t.confirm_hits == 0 {
        return Err(c.invalid("v2x.tracker.confirm_hits", "need at least 1 hit".into()));
    }
    Ok(TrackerSettings {
        accel_sigma_mps2: t.accel_sigma_mps2,
        gate_chi2: t.gate_chi2,
        confirm_hits: t.confirm_hits,
        max_coast_s: t.max_coast_s,
        birth_speed_sigma_mps: t.birth_speed_sigma_mps,
        appearance_sigma: t.appearance_sigma,
        reid_s: t.reid_s,
    })
}

fn cpm(c: &Checker, m: RawCpm) -> Result<CpmSettings, ConfigError> {
    if !(1.0..=10.0).contains(&m.rate_hz) {
        return Err(c.invalid(
            "v2x.cpm.rate_hz",
            format!(
                "must be in [1, 10] Hz (T_GenCpm 0.1-1 s), got {}",
                num(m.rate_hz)
            ),
        ));
    }
    c.positive(field!("v2x.cpm", m.position_change_m))?;
    c.positive(field!("v2x.cpm", m.speed_change_mps))?;
    c.positive(field!("v2x.cpm", m.heading_change_deg))?;
    c.positive(field!("v2x.cpm", m.max_interval_s))?;
    if !(1..=MAX_CPM_OBJECTS).contains(&m.max_objects) {
        return Err(c.invalid(
            "v2x.cpm.max_objects",
            format!("must be 1 to {MAX_CPM_OBJECTS}, got {}", m.max_objects),
        ));
    }
    Ok(CpmSettings {
        rate_hz: m.rate_hz,
        position_change_m: m.position_change_m,
        speed_change_mps: m.speed_change_mps,
        heading_change_deg: m.heading_change_deg,
        max_interval_s: m.max_interval_s,
        max_objects: m.max_objects,
    })
}

fn channel(c: &Checker, ch: RawChannel) -> Result<ChannelSettings, ConfigError> {
    c.non_negative(field!("v2x.channel", ch.latency_s))?;
    c.non_negative(field!("v2x.channel", ch.jitter_mean_s))?;
    c.fraction(field!("v2x.channel", ch.loss_probability))?;
    c.positive(field!("v2x.channel", ch.loss_range_m))?;
    Ok(ChannelSettings {
        latency_s: ch.latency_s,
        jitter_mean_s: ch.jitter_mean_s,
        loss: match ch.loss {
            LossKind::Independent => LossModel::Independent {
                probability: ch.loss_probability,
            },
            LossKind::Distance => LossModel::Distance {
                probability_at_0: ch.loss_probability,
                range_m: ch.loss_range_m,
            },
        },
    })
}
