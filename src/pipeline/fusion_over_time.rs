//! Fusion of what a receiver associated with one peer, scored against the
//! truth: once per reception ([`fuse_pairs`]: single, Eq. 14-16,
//! covariance intersection) and recursively into a running estimate per
//! ego track ([`RecursiveFusion`], where the independent form counts the
//! same information again: [`nees`] shows it).

use std::collections::BTreeMap;

use super::context::Context;
use super::peer::Views;
use super::vehicle::ConnectedVehicle;
use crate::fusion::{Fused, Measurement, covariance_intersection, fuse, relative_pose_prior};
use crate::geometry::{Cov2, Vec2};
use crate::report::OverTimeCounts;
use crate::sensor::Detection;

/// A detection as a measurement to fuse: its position and covariance.
pub(super) fn measurement(d: &Detection) -> Measurement {
    Measurement {
        position_m: d.position_m,
        cov_m2: d.cov_m2,
    }
}

/// A fused estimate as a measurement to fuse again.
fn estimate(f: &Fused) -> Measurement {
    Measurement {
        position_m: f.position_m,
        cov_m2: f.cov_m2,
    }
}

/// Ego tracks fused with the peer objects `pairs` associates them with:
/// the summed errors single, by Eq. 14-16 and by covariance intersection,
/// against the object's true centre in the receiver's body frame, and
/// their count.
pub(super) fn fuse_pairs(
    ctx: &Context,
    receiver: &ConnectedVehicle,
    views: &Views,
    pairs: &[(u64, u64)],
) -> (f64, f64, f64, u64) {
    let prior = relative_pose_prior(
        &receiver.reported_poses()[0],
        &views.peer_reported,
        ctx.level().position_sigma_m,
        ctx.level().heading_sigma_rad,
    );
    let body = receiver.pose().inverse();
    let mut out = (0.0, 0.0, 0.0, 0);
    for &(e, p) in pairs {
        let (Some(a), Some(b)) = (
            views.ego_ids.iter().position(|&x| x == e),
            views.peer_ids.iter().position(|&x| x == p),
        ) else {
            continue;
        };
        let Some(truth) = views.ego_truth[a]
            .as_deref()
            .and_then(|o| ctx.truth.get(o))
            .map(|w| body.to_parent(w))
        else {
            continue;
        };
        let ego = measurement(&views.ego[a]);
        let peer = measurement(&views.peer[b]).moved_uncertain(&prior);
        let (Some(ind), Some(ci)) = (fuse(&[ego, peer]), covariance_intersection(&[ego, peer]))
        else {
            continue;
        };
        out.0 += (ego.position_m - truth).norm();
        out.1 += (ind.position_m - truth).norm();
        out.2 += (ci.position_m - truth).norm();
        out.3 += 1;
    }
    out
}

/// A recursively fused estimate of one ego track with one peer object, in
/// the receiver's tracking frame, by Eq. 14-16 and by covariance
/// intersection.
#[derive(Clone, Copy)]
struct Recursive {
    peer: u64,
    time_s: f64,
    independent: Measurement,
    ci: Measurement,
}

/// Per ego track associated with one peer: its recursively fused
/// estimate.
#[derive(Default)]
pub(super) struct RecursiveFusion {
    fused: BTreeMap<u64, Recursive>,
}

impl RecursiveFusion {
    /// Updates each associated ego track's recursive estimate with the ego
    /// track and the peer's object of this reception (a track whose
    /// association changed starts again), and scores it against the truth.
    pub(super) fn update(
        &mut self,
        ctx: &Context,
        receiver: &ConnectedVehicle,
        views: &Views,
        pairs: &[(u64, u64)],
        c: &mut OverTimeCounts,
    ) {
        let prior = relative_pose_prior(
            &receiver.reported_poses()[0],
            &views.peer_reported,
            ctx.level().position_sigma_m,
            ctx.level().heading_sigma_rad,
        );
        let mut next = BTreeMap::new();
        for &(e, p) in pairs {
            let (Some((track, track_cov)), Some(b)) = (
                receiver.track(e),
                views.peer_ids.iter().position(|&x| x == p),
            ) else {
                continue;
            };
            let ego = Measurement {
                position_m: track.position_m,
                cov_m2: *track_cov,
            };
            let body = measurement(&views.peer[b]).moved_uncertain(&prior);
            let peer = body.moved(&receiver.pose());
            let grow = |m: Measurement, dt: f64| Measurement {
                position_m: m.position_m + track.velocity_mps * dt,
                cov_m2: m.cov_m2
                    + Cov2::identity() * (ctx.v.tracker.accel_sigma_mps2 * dt * dt / 2.0).powi(2),
            };
            let previous = self.fused.get(&e).filter(|r| r.peer == p);
            let (ind, ci) = match previous {
                Some(r) => {
                    let dt = ctx.time_s - r.time_s;
                    (
                        fuse(&[grow(r.independent, dt), ego, peer]),
                        covariance_intersection(&[grow(r.ci, dt), ego, peer]),
                    )
                }
                None => (fuse(&[ego, peer]), covariance_intersection(&[ego, peer])),
            };
            let (Some(ind), Some(ci), Some(once), Some(once_ci)) = (
                ind,
                ci,
                fuse(&[ego, peer]),
                covariance_intersection(&[ego, peer]),
            ) else {
                continue;
            };
            next.insert(
                e,
                Recursive {
                    peer: p,
                    time_s: ctx.time_s,
                    independent: estimate(&ind),
                    ci: estimate(&ci),
                },
            );
            let truth = receiver
                .label(e)
                .and_then(|l| l.truth.as_deref())
                .and_then(|o| ctx.truth.get(o));
            if let Some(&truth) = truth {
                c.recursive_fused_sum_m += (ind.position_m - truth).norm();
                c.recursive_ci_sum_m += (ci.position_m - truth).norm();
                c.recursive_nees_fused_sum += nees(&estimate(&ind), truth);
                c.recursive_nees_ci_sum += nees(&estimate(&ci), truth);
                c.once_nees_fused_sum += nees(&estimate(&once), truth);
                c.once_nees_ci_sum += nees(&estimate(&once_ci), truth);
                c.recursive_n += 1;
            }
        }
        self.fused = next;
    }
}

/// The normalised estimation error squared of `m` against `truth`:
/// `e^T P^-1 e`, 2 on average (two dimensions) when the claimed
/// covariance is honest.
pub(super) fn nees(m: &Measurement, truth: Vec2) -> f64 {
    let e = m.position_m - truth;
    m.cov_m2
        .try_inverse()
        .map_or(f64::NAN, |inv| (e.transpose() * inv * e)[0])
}
