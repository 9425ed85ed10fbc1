//! The walk pass of a run: after every frame is fused, each frame's regions are
//! followed along the walk ([`crate::fusion::walk`]) and the frames whose
//! regions the walk holds are fused again with those holds.

use super::FrameRecord;
use crate::fusion::walk::{mends, Mend, WalkParams, WalkRegion};
use crate::scene::Scene;
use glam::Vec3;

/// The regions of a frame's ledger as the walk sees them (world axes, the
/// power added before any hold of the walk's).
fn regions(scene: &Scene, i: usize, rec: &FrameRecord) -> Vec<WalkRegion> {
    let Some(fu) = &rec.fusion else {
        return Vec::new();
    };
    let to_world = scene.frames[i].pose.world_from_camera;
    fu.ledger
        .iter()
        .filter_map(|e| {
            let dir = (to_world * Vec3::from_array(e.dir)).normalize_or_zero();
            let solid_angle = fu.blobs.get(e.region)?.solid_angle_sr;
            let added = e.walk.map_or(e.added, |w| w.before);
            // What the probes' radiance gives the region pixel by pixel (a
            // light carried through its surface, a far source where the lookup
            // covers it); a placed light's or the probes' budget includes the
            // base estimate's own power, and a far source's pixels the lookup
            // does not cover are extrapolated.
            let supported = e.measured.min(added);
            (dir != Vec3::ZERO).then_some(WalkRegion {
                region: e.region,
                dir,
                solid_angle,
                added,
                supported,
            })
        })
        .collect()
}

/// The holds each frame of the walk should have, in walk order.
pub(super) fn wanted(scene: &Scene, records: &[FrameRecord], p: &WalkParams) -> Vec<Vec<Mend>> {
    let frames: Vec<Vec<WalkRegion>> = records
        .iter()
        .enumerate()
        .map(|(i, r)| regions(scene, i, r))
        .collect();
    let positions: Vec<Vec3> = scene.frames.iter().map(|f| f.pose.position).collect();
    mends(&frames, &positions, p)
}

/// The holds a frame's outputs were made with.
pub(super) fn held(rec: &FrameRecord) -> Vec<Mend> {
    rec.fusion
        .iter()
        .flat_map(|f| f.ledger.iter())
        .filter_map(|e| {
            e.walk.map(|w| Mend {
                region: e.region,
                power: w.power,
            })
        })
        .collect()
}
