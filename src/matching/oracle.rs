//! The oracle: pairs detections with the same true object id. It bounds what
//! fusion can reach with perfect correspondences; it is the only matcher that
//! reads the evaluation-only `truth_id`.

use super::{Correspondence, MatchView, Matcher, Method};

pub struct Oracle;

impl Matcher for Oracle {
    fn method(&self) -> Method {
        Method::Oracle
    }

    fn match_pair(&self, first: &MatchView, second: &MatchView) -> Vec<Correspondence> {
        let mut out = Vec::new();
        for (a, da) in first.detections.iter().enumerate() {
            let Some(id) = &da.truth_id else { continue };
            if let Some(b) = second
                .detections
                .iter()
                .position(|db| db.truth_id.as_ref() == Some(id))
            {
                out.push(Correspondence {
                    a,
                    b,
                    probability: 1.0,
                    uncertainty: 0.0,
                });
            }
        }
        out
    }
}
