//! The library itself, SUMO included, in this test process: the untrained
//! deep methods decide as GPS+appearance Hungarian.

use coid_sim::config::Settings;
use coid_sim::matching::deep::{self, Inference};
use coid_sim::matching::{GpsHungarian, Matcher, Method};
use coid_sim::pipeline;

use crate::util::*;

/// Untrained (the residual's gate at zero), every deep method that uses
/// positions decides exactly as GPS+appearance Hungarian does, pair for
/// pair, on every instance of a real scene (the shipped intersection
/// through the real bridge, 60 s, every pose-noise level): they start
/// from the same likelihood and the same assignment.
#[test]
fn the_untrained_residual_reproduces_gps_appearance_hungarian_on_a_real_scene() {
    let fx = Fixture::new();
    let settings = Settings::load(&fx.config("u.toml", 60.0, "")).unwrap();
    let hungarian = GpsHungarian {
        gate_chi2: settings.matching.gate_chi2,
        appearance: true,
        descriptor_weight: 1.0,
    };
    let run = Inference {
        samples: 4,
        masks: settings
            .matching
            .dropout_masks
            .resolve(coid_sim::matching::deep::arch::MaskScope::PerNode),
        dropout: settings.matching.mc_dropout,
        gate_chi2: settings.matching.gate_chi2,
        ..Inference::MC_DROPOUT
    };
    let deep: Vec<Box<dyn Matcher>> = [
        Method::Ours,
        Method::CoidNonGps,
        Method::CoidUncGps,
        Method::DgmcGps,
        Method::GcnGmGps,
    ]
    .iter()
    .map(|&m| {
        assert!(m.architecture().is_some(), "{m:?} sees the poses");
        deep::untrained(m, 7, run)
    })
    .collect();
    let pairs = |m: &dyn Matcher, pair: &coid_sim::evaluate::PairAtLevel| -> Vec<(usize, usize)> {
        let id = m.identify(&pair.first.view, &pair.second.view);
        id.matches.iter().map(|c| (c.a, c.b)).collect()
    };
    let mut compared = 0;
    pipeline::simulate(
        &settings,
        &pipeline::Warnings::default(),
        |_| {},
        |inst| {
            for level in &settings.pose_noise {
                let speed_sigma = settings.v2x.gnss_heading_speed_sigma_mps;
                let pair = inst.at_level(settings.seeds.sensor, level, speed_sigma);
                let expected = pairs(&hungarian, &pair);
                for m in &deep {
                    assert_eq!(
                        pairs(&**m, &pair),
                        expected,
                        "{:?} at step {}",
                        m.method(),
                        inst.frame.step
                    );
                }
                compared += expected.len();
            }
            Ok(())
        },
    )
    .unwrap();
    assert!(compared > 100, "only {compared} pairs compared");
}
