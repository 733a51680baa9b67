//! Correct: visual forces (spec section 2, "Correct"). After each predict step, Adam moves the
//! tracked objects' Gaussians to reduce the photometric error against the camera images; each
//! Gaussian's displacement becomes a force on its parent particle (gain x displacement, averaged
//! over the particle's Gaussians; the particle's mass acts as visual inertia) that the next predict
//! step applies. The world's
//! Gaussians are never modified: the optimisation runs on a copy that is dropped afterwards.
//!
//! This module owns the optimisation and the force rule; it renders through `render` and leaves
//! the integration of the forces to `physics`.

pub mod adam;
pub mod agreement;
pub mod backdrop;
pub mod friction;
pub mod nudge;
pub mod plant;
pub mod pull;
pub mod relocate;
pub mod spread;

use crate::render::{
    self, Backend, Camera, GaussianCloud, PixelGrads, RenderSettings, Renderer, Roi,
};
use crate::world::{NO_PARENT, ShapeId, ShapeKind, World};
use adam::Adam;
use anyhow::{Result, bail};
use backdrop::Backdrop;
pub use friction::{FrictionMemory, Support, compensate_friction};
use glam::{Vec3, Vec4};
pub use plant::{Plant, loop_gains};
pub use pull::{PullState, pose_pulls, pull_share};
use serde::{Deserialize, Serialize};
use spread::{ROPE_SPREAD, spread_along_ropes, spread_over_rigid_bodies};

/// Every number of the correction step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CorrectConfig {
    pub enabled: bool,
    pub backend: Backend,
    /// Adam iterations per tick (moments reset every tick).
    pub iterations: u32,
    /// Cameras rendered in each Adam iteration, taken in turn across iterations and ticks
    /// (0: every camera in every iteration). One per iteration is the paper's choice: the cost of
    /// a tick is then `iterations` renders whatever the number of cameras.
    pub cameras_per_iteration: u32,
    /// A Gaussian's mean takes Adam steps along its gradient (one second moment for x, y and z)
    /// rather than per coordinate, so the steps do not depend on the world's axes.
    pub isotropic_means: bool,
    /// Learning rates: means (m), rotations (quaternion units), colours, opacity logits.
    pub lr_mean: f32,
    pub lr_rotation: f32,
    pub lr_colour: f32,
    pub lr_opacity: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub epsilon: f32,
    /// Adam's epsilon grows by this times the median RMS gradient of the Gaussians
    /// (`Adam::with_noise_floor`): a Gaussian whose gradient is well below the typical one
    /// (image noise where rendering and image agree) steps in proportion to its gradient
    /// instead of by a full lr, so noise makes smaller visual forces. 0: plain Adam.
    pub noise_floor: f32,
    /// Acceleration per metre of Gaussian displacement, 1/s^2: a particle's force is its visual
    /// mass (`force_mass`) times the gain times its Gaussians' mean displacement, so the
    /// same gain moves every object alike whatever its mass and particle count.
    pub gain: f32,
    /// Acceleration per metre per second of change in a Gaussian's displacement between ticks,
    /// 1/s: the derivative term the paper suggests against the spring-like oscillation of visual
    /// forces. `gain` and `damping` are set once for every scene; the model they push scales
    /// the gain (`plant::loop_gains`) by the three settings below.
    pub damping: f32,
    /// Tables whose kinetic friction (the model's) is under this damp the loop too little for
    /// `gain`: it falls in proportion to the friction, down to `slippery_floor` of it on a
    /// frictionless table (`damping` stays).
    pub slippery_friction: f32,
    pub slippery_floor: f32,
    /// The share of its velocity a particle keeps each tick (`physics.damping`) `gain` is set
    /// for: a model keeping less takes reference / kept times the gain.
    pub reference_damping: f32,
    /// Acceleration per metre second of a Gaussian's displacement integrated over the ticks,
    /// 1/s^3, with the integral leaking at `integral_leak` (1/s). Against a steady displacement
    /// the integral settles at displacement / leak, so the force's steady part is (gain +
    /// integral / leak) x displacement while its quick part stays gain x displacement: stiff
    /// enough to beat static friction, soft enough not to ring on a slippery table. 0: off.
    pub integral: f32,
    pub integral_leak: f32,
    /// A rigid object's Gaussians push it in proportion to their RMS gradient over the tick
    /// (relative to the object's mean, so a body whose Gaussians all moved by d still
    /// accelerates at gain x d): its edges, which see where it is, count more than its
    /// uniform inside, whose steps are image noise. false: every Gaussian counts alike.
    pub weight_by_gradient: bool,
    /// A rope particle's visual inertia in multiples of its mass: a rope covers few pixels, so its
    /// Gaussians' displacements are noisier than a solid's (the paper gives rope particles more
    /// mass for the same reason).
    pub rope_inertia: f32,
    /// Displacements shorter than this (m) are ignored.
    pub min_displacement: f32,
    /// Where a tracked object's Gaussians, moved and turned as one, agree better with the images
    /// within this radius (m) of where the model has it (`relocate::Search::local`), the offset
    /// beyond `pose_dead_zone` pulls it there (acceleration `pose_gain` x offset + `pose_damping`
    /// x its change per second + `pose_integral` x its integral over the ticks it has lasted, so
    /// that a constant force the model lacks, or its static friction, is overcome without a
    /// standing offset). Adam's steps are bounded (about iterations x lr_mean a tick), so their
    /// forces cannot grow with the error past a few mm and vanish once the rendered object no
    /// longer overlaps the observed one; this offset does both. 0 turns it off.
    pub pose_search_radius: f32,
    /// The search also scores points this far (m) outside the object's outline, which must show
    /// the static scene (`relocate::Probe::add_ring`). 0: the object's own Gaussians only.
    pub pose_search_ring: f32,
    /// Where a camera sends depth aligned to its colour (`node.depth_topic`, each frame with the
    /// colour's stamp), the pose search also checks it: an object's Gaussian matches only where
    /// the depth measured at its pixel lies within this (m) plus its size of its own, a ring
    /// point only where nothing stands this far in front of it; a pixel something nearer than
    /// the whole object covers counts neither way (`relocate::Probe::depth_agrees`), and the
    /// Gaussians whose depth disagreed where the object was built are scored by colour alone
    /// (`relocate::depth_trusted`). Colour from another renderer is biased at rest by as much
    /// as a real offset pulls; depth is not. 0: colour alone, and the node reads depth for
    /// initialisation only (set it at start: the subscription is chosen then).
    pub pose_search_depth: f32,
    /// Where a camera sends depth (`pose_search_depth` > 0), the ring's points
    /// (`pose_search_ring`) are judged by it alone: a point matches where nothing stands more
    /// than `pose_search_depth` in front of it, whatever its colour; on a pixel without depth,
    /// by colour as before. The colour just outside an object another renderer drew (its
    /// shadow, its blurred edge) can look like the object and push a resting object's found
    /// pose off; its depth does not. false: colour and depth both (README, "The ring judged by
    /// depth").
    pub pose_search_ring_by_depth: bool,
    pub pose_gain: f32,
    /// Soft (10, not 30): the offset is measured once a tick on a grid of a third of a
    /// centimetre, so its change per second jumps by a grid step at a time, and with the pull held
    /// through searches without a verdict (`PULL_HOLD_TICKS`) a rate term of 30 kicked MuJoCo's
    /// sticky_501 bar 12 deg one way and 18 the other every tick.
    pub pose_damping: f32,
    pub pose_integral: f32,
    /// Damping (1/s, scaled by `pull_share`) of each pulled particle's velocity against the
    /// found pose's velocity there (`PullState::acceleration_following`): the pull's own loop
    /// damped on the velocity the physics integrates, not on the grid-found offset's rate, whose
    /// steps kick (`pose_damping`). 0: off.
    pub pose_follow_damping: f32,
    /// Share (0-1) of each tick's found velocity the smoothed one takes (an exponential average;
    /// 0.3: about three ticks, a grid step's kick spread over them).
    pub pose_follow_smoothing: f32,
    /// Offsets (m, at the object's furthest particle) up to this are left to the Gaussians.
    pub pose_dead_zone: f32,
    /// The search runs for objects whose silhouette agreement (`agreement`, averaged over the
    /// last few ticks) is below this; at 1, for every object short of full agreement (where
    /// `pull_share` leaves nothing to pull; over 1, for every object). It scores only what
    /// each camera sees of the object (`relocate`: Gaussians behind its near side, and pixels
    /// the robot or another object covers, count neither way). Before that, a gate of 0.9 was
    /// needed: pegs's painted box, tracked within 0.8 mm, scored its own pose 0.90 and one 5-7
    /// mm away 0.94, and a box the rod pushed was drawn out from under the rod.
    pub pose_search_below: f32,
    /// Below this agreement the pose pull acts in full; between it and `pose_search_below` it
    /// grows from nothing as the agreement falls (`pull_share`; none at full agreement by
    /// default), so an object the Gaussians already track, more finely than the search's grid, is
    /// pulled a little and one visibly off in full. At or above `pose_search_below`: in full
    /// wherever the search runs.
    pub pose_pull_full_below: f32,
    /// Share (0-1) of a convincing found pose's offset beyond `pose_nudge_beyond` that the
    /// tracked state takes at once each tick (`nudge`: the object's particles moved rigidly
    /// towards it, in proportion to `pull_share`; none for an object the model has touching the
    /// robot or another object), before the pull acts on what is left. 0: the pull alone.
    pub pose_nudge: f32,
    /// Share of the nudge's rate (its move / dt) added to the object's velocity.
    pub pose_nudge_velocity: f32,
    /// The nudge takes only the offset beyond this (m, at the furthest particle): a found pose
    /// within it is left to the pull, whose force the model's friction filters.
    pub pose_nudge_beyond: f32,
    /// An object the model has touching the robot or another object is nudged only beyond this
    /// (m, at the furthest particle), and settled for the next tick (`Solver::settle_below`, no
    /// faster than it moves): what the nudge puts into its pusher is pushed out in position, not
    /// thrown; only once the search has found it that far off two ticks running
    /// (`nudge::found_beyond`). 0: such an object is not nudged (README, "A nudge in contact").
    pub pose_nudge_contact_beyond: f32,
    /// Images older than this (s) at a tick are not used. An image shows the objects where they
    /// were when it was taken, and the tick compares it with the world at the tick's end: at
    /// 0.2 m/s every 10 ms of age pulls the objects 2 mm back. About two ticks by default (a
    /// camera's newest image is up to a frame period plus its transport old); a camera that
    /// stopped publishing drops out instead of pulling the objects towards where they were.
    pub max_image_age: f32,
    /// Render only the window around the tracked objects' footprint (plus this margin, px).
    pub use_roi: bool,
    pub roi_margin_px: f32,
    /// Unmodelled occluders (an arm without joint states, a hand): a pixel whose colour is further
    /// than this (RGB distance, colours in [0, 1]) from the static scene rendered there, and whose
    /// chromaticity is this far from every colour the tracked objects render with (brightness free
    /// within a factor 2.5: shading), is left out of the loss. 0 uses every pixel.
    pub occluder_threshold: f32,
    /// Share of the model's own kinetic friction (`Support`) added to the visual force of an
    /// object standing on the table, against its push along the table and its turn about the
    /// table's normal as averaged over the last few ticks (`compensate_friction`), ramped in
    /// over `friction_ramp` (m/s^2 of averaged push). The model's friction is a dead zone in the
    /// loop the visual forces close: without it a gain soft enough not to ring on a slippery
    /// table cannot break a box free on a rough one. The compensation is applied, not reported
    /// in `CorrectStats::force` (what the model lacks). 0: off.
    pub friction_compensation: f32,
    pub friction_ramp: f32,
    /// The displacement (m) within which the visual force is left to overcome the model's
    /// friction by itself: a table whose kinetic friction is under `gain x friction_hold` is not
    /// compensated (on a slippery table the friction is what keeps a tracked object still at
    /// rest: compensated, image noise rings it), one over twice that in full, in proportion
    /// between (`beyond_hold`). A turn likewise, `friction_hold` measured at the feet.
    pub friction_hold: f32,
}

impl Default for CorrectConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            backend: Backend::Cpu,
            iterations: 5,
            cameras_per_iteration: 1,
            isotropic_means: true,
            lr_mean: 0.0015,
            lr_rotation: 0.001,
            lr_colour: 0.0,
            lr_opacity: 0.0,
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-8,
            noise_floor: 0.0,
            // Rounds 1-3 below were measured when the gain was a force per particle (N/m, N s/m)
            // on the built-in objects' 1 g particles, every one carrying Gaussians: multiply by
            // 1000 for today's accelerations (gain 1.5 then is 1500 now, damping 0.05 is 50).
            // Round 4, the scenario table's mean error (mm) averaged over three start offsets
            // (1 cm / 5 deg as the table, 1 cm / -5 deg, 1.2 cm / 3 deg): every camera in each of 5
            // iterations (15 renders), rope visual inertia 1 -> rope 39.5 | resting box 1.30 |
            // pushed box 1.86 | T-block 2.96 | T-block over 2.38 | two boxes 1.46 / 2.22 | hidden
            // box 11.2; inertia 2 -> 9.3 | 1.32 | 1.86 | 2.68 | 2.62 | 1.60 / 2.34 | 11.2; one camera
            // per iteration with isotropic mean steps (5 renders) -> 9.9 | 1.30 | 0.78 | 1.88 | 2.75
            // | 0.92 / 1.03 | 11.4; the same with 3 iterations at lr 0.0025 -> 9.8 | 2.23 | 1.41 |
            // 2.07 | 8.24 | 1.27 / 1.03 | 8.5; 6 iterations -> 9.8 | 2.06 | 1.11 | 2.30 | 1.96 | 1.36
            // / 2.24 | 11.1. One camera per iteration without isotropic steps lost the hidden box
            // (40-43 mm) in 4 of 5 settings: single-camera gradients have noisy signs along rays.
            // Tuned at 3 x 320x180 with 1 g particles, mean tracking error (resting box from
            // 3 cm / 20 deg | from 1 cm / 5 deg | pushed box | pushed T-block, both from 1 cm / 5 deg).
            // Round 1, forces on the particles whose Gaussians moved: gain 1.5 -> 18.7 | - | 5.0 | -,
            // 2 -> 3.5 | 8.0 | 4.1 | 11.9, 3 -> 46.9 | - | 22.6 | - mm (4 and above diverge); the
            // derivative term did not help (2 + damping 0.03 -> 9.4 | - | 3.9; 3 + 0.05 -> 20.4 | - | 5.3).
            // Round 2, forces spread as rigid-body accelerations (`spread_over_rigid_bodies`):
            // gain 1 -> 13.2 | 8.9 | 4.9 | 5.0, 1.5 -> 5.8 | 4.9 | 2.9 | 4.2, 2 -> 15.9 | 4.0 | 2.5 |
            // 7.6, 2.5 -> 47.5 | 20.0 | 7.4 | 13.8, 3 -> 293 | 64 | 27 | 28 mm. Without damping a
            // resting object stops about 4.7 mm off, where the force falls below static friction.
            // Round 3, gain 1.5 with the derivative term (error at 2 s from 3 cm / 20 deg | pushed
            // box | T-block | two boxes, mean): damping 0 -> 4.7 | 2.9 | 4.2 | 2.6, 0.05 -> 2.3 |
            // 1.3 | 2.7 | 2.2, 0.08 -> 1.2 | 1.5 | 4.3 | 1.7 mm. Visual forces alone (no gravity,
            // ground or collisions), pushed box: damping 0 diverges (551 mm mean), 0.05 -> 16.9 mm.
            // Round 5, towards one setting for the scenarios and the slippery concealed table
            // (`noise_floor` and `integral`, both off; each recording replayed with only these
            // changed). Scenario rows (rope | hidden box | pushed box | T-block | resting box |
            // T-block over | two boxes) over round 4's three offsets: defaults 6.31 | 10.65 | 0.70
            // | 2.22 | 1.08 | 2.13 | 0.85 / 1.18; floor 0.5 -> 6.10 | 15.56 | 0.55 | 1.53 | 0.85 |
            // 2.68 | 0.69 / 0.73 (smaller steps, smaller forces: the hidden box's unmodelled pull
            // wins); floor 0.5 + integral 2000 (leak 2) -> 6.11 | 7.92 | 0.78 | 1.14 | 1.44 | 1.48
            // | 1.02 / 1.04. Concealed recordings (9 objects, one offset): their 500 / 40 ->
            // 0.95-1.54; the defaults -> 5.6-8.7 (a 6-tick limit cycle); floor 0.5 -> 2.7-4.2;
            // floor 0.5 + integral 2000 -> 4.5-5.5; gain 1000 / 40 with floor 0.5 -> 0.9-1.2, but
            // static friction then holds the resting box 6.5 mm off (pushed box 2.8, T-block over
            // 6.4); adding integral 2000 with leak 0.5 -> concealed 1.0-1.5, resting box 2.6,
            // pushed box 1.6, two boxes 2.7 / 1.9. No pair meets both: a quick gain soft enough
            // for the slippery table is too weak against static friction, and a slow integral
            // strong enough to make up for it rings there again.
            // Round 6, `weight_by_gradient` (a rigid object's seen Gaussians push it in proportion
            // to their RMS gradient, at most 3x the object's mean), everything else at these
            // defaults. Scenario rows as round 5 -> 6.31 | 8.73 | 1.11 | 2.18 | 1.44 | 2.84 | 1.21
            // / 0.97 (the hidden box better; the pushed and resting boxes, the T-block over and
            // one of the two boxes 30-60 % worse, all within 1.5 mm); concealed recordings with
            // their own 500 / 40 -> 1.04-1.27, at these defaults 11-16 (it stiffens the push, so
            // it rings more). Where it helps is data pegs did not make: MuJoCo's model-error
            // recordings (seeds 300-302) 15 -> 20 of 24 objects under 5 mm (slippery T-block 9.2
            // -> 4.1, heavy5_300's boxes 4.6 / 5.3 -> 3.9 / 8.1); the real T-block at these
            // defaults IoU 0.651 / 0.624 / 0.314 -> 0.786 / 0.767 / 0.337 (its import's 5800 / 24:
            // 0.796 / 0.790 / 0.327). Uncapped, the hidden box was thrown 43 cm (the few seen
            // Gaussians of a box behind the arm took its whole push).
            // Round 7, `weight_by_gradient` with softer gains, scenario rows as round 5: 500 / 40
            // (the concealed recordings' own) -> 7.02 | 20.35 | 2.61 | 2.30 | 5.93 | 7.52 | 2.73
            // / 4.25 (static friction holds the resting box 6 mm off); 1000 / 50 -> 6.28 | 12.22 |
            // 1.46 | 1.91 | 2.53 | 1.49 | 2.20 / 1.80; 1200 / 60 -> 6.31 | 9.49 | 0.68 | 2.38 |
            // 1.23 | 3.52 | 1.93 / 2.66. Weighting does not buy a softer gain for pegs's scenes.
            // Round 8, `friction_compensation` 1 (a steady push along the table gains the
            // model's kinetic friction, a steady turn its friction torque, while the object
            // stands on a face) with `weight_by_gradient`, scenario rows as round 5: 800 / 40
            // without the turn -> 6.00 | 3.41 | 0.78 | 1.66 | 0.94 | 1.50 | 0.95 / 0.95; 600 / 40
            // without the turn -> 6.01 | 5.05 | 0.55 | 1.71 | 1.37 | 0.95 | 0.78 / 0.95 (the
            // resting box held off in yaw); 600 / 40 with it -> 6.01 | 5.45 | 0.68 | 2.07 | 0.93
            // | 1.76 | 0.69 / 1.06, every row within 10 % of these defaults' and the hidden box
            // halved. Concealed recordings at that setting 1.35-2.38 (800 / 40: 1.95-3.53; their
            // own 500 / 40: 0.95-1.54), the real T-block's IoU 0.776 / 0.754 / 0.334 (its
            // import's own 0.796 / 0.786 / 0.327; with its model's velocity damping 0.9 instead
            // of 0.5, 0.731 / 0.726 / 0.308). Compensating every tick's push instead of its
            // running average let image noise move boxes at rest (pushed box 1.15, resting box
            // 1.5 mm, static friction compensated), and compensating a body tipping over its edge
            // let the edge slide out (T-block pushed over 4.5 mm, p95 24). On MuJoCo's
            // model-error recordings (fresh seeds 400-402, dead zone 3 mm) 600 / 40 with both
            // tracked 18 of 24 objects under 5 mm against these defaults' 21: what the model
            // does not have at all and moves fast lags behind a softer gain (the hand's pushes
            // 11.1 / 11.0 / 6.2 mm against 6.1 / 7.1 / 2.3, two slides on a slippery table 8.5
            // and 9.5 against 4.1 and 3.6); the sticky table's box 5.4 -> 3.9.
            // Round 9, why 600 / 40 with both fails concealed_tilt's diagnosis: its box rings at
            // rest on the slippery table (a period of 4-5 ticks, 2 mm along y), which sets the
            // locator's threshold (see `diagnose::locate`) above the tilt's 0.2 s misses. Median
            // tracked motion in 0.2 s while the true box rests (tracking error): its own 500 / 40
            // 0.28 mm (1.43); 600 / 40 with both 1.57 (1.60); without weighting 0.42 (1.46);
            // without compensation 0.73 (1.24); these defaults 2.39 (6.63). With both, damping
            // 20 -> 0.61 (1.23), 30 -> 0.56 (1.17), 55 -> 3.54 (2.65): the derivative of a
            // displacement measured afresh each tick kicks at the tick rate. 450 / 30 -> 0.42
            // (1.13); integral 3000 (leak 2) -> 1.89, noise_floor 1 -> 1.48. Rows at 450 / 30
            // with both: 6.08 | 7.73 | 1.22 | 1.83 | 1.31 | 1.71 | 1.27 / 0.88, concealed
            // 0.96-1.26 (the pushed box and the two boxes lag). Likewise 600 / 30 loses
            // pegs's rough table (rows as round 5: 6.06 | 4.80 | 1.02 | 2.31 | 2.42 | 2.09 | 1.04 /
            // 1.05; the resting box held off by static friction), as does 600 / 40 without
            // weighting (6.01 | 10.75 | 0.83 | 2.37 | 1.24 | 1.77 | 1.04 / 1.68). Withholding the
            // compensation while the model moves against the averaged push: jitter 1.22, rows
            // 6.13 | 5.22 | 1.02 | 1.80 | 1.14 | 1.17 | 1.00 / 1.17, concealed 1.13-2.02 (pushed
            // box and two boxes lost; not kept). The real T-block at 600 / 40 with both: lr
            // 0.0015 -> IoU 0.776 / 0.754 / 0.334, 0.003 -> 0.780 / 0.766 / 0.336, damping 30 ->
            // 0.773 / 0.748 / 0.329, integral 3000 -> 0.767 / 0.742 / 0.335 (its import's 0.796
            // / 0.790 / 0.327).
            // Round 10, `friction_hold` 1 mm (the compensation leaves a table's friction to the
            // visual force while it is under gain x 1 mm: none of the concealed table's 0.29
            // m/s^2 is made up at gain 600, all of the rough table's 3.9). 600 / 40 with
            // compensation and weighting: rows as round 5 6.01 | 5.63 | 0.63 | 2.01 | 0.93 | 1.76
            // | 0.69 / 1.05, concealed 1.07-1.38, concealed_tilt's jitter as round 9 1.57 -> 0.73
            // (1.24), and its diagnosis names the constant force (0.064 N against 0.062, 97 %
            // cross-validated; the locator's threshold 3.0 mm); the cord is named too (0.89 N/m
            // against 0.8, 1 s error 53.8 -> 5.8 mm), the weight's offset as well (16.5 mm
            // against 15) but its 1 s error only 14.7 -> 13.0 mm, not halved (12.7 -> 5.5 at
            // 500 / 40): that row fails. Hold 0.5 mm, a floor of 0.3 m/s^2
            // of friction kept on every table, lost the rough one (6.01 | 4.84 | 0.85 | 2.13 |
            // 1.47 | 1.54 | 0.80 / 1.34). Gating the compensation on the push's steadiness (its
            // running average over its average size, 0.6-0.95 for none) instead: jitter 0.63-0.94
            // but the resting box 2.5-4.7 mm (a box static friction holds 1-3 mm off is pushed as
            // unsteadily as noise). A smoothed derivative (the rate's running average, weight 0.5)
            // rang 6 mm: its lead is what damps. Stiffer gains ring with or without the
            // compensation (800 / 40: 1.57 mm, 1000 / 50: 3.54), and smaller steps under a
            // stiffer gain as much (1200 / 40 at lr 0.00075: 1.43; 2000 / 50 at 0.0005: 1.61).
            // Not the default yet: the real T-block at 600 / 40 with hold 0.774 / 0.739 / 0.333,
            // and MuJoCo's model errors (seeds 400-402) 20 of 24 objects under 5 mm against
            // these defaults' 21, the hand's pushes 11.8 / 11.5 / 3.6 mm (6.1 / 7.1 / 2.3) and
            // the slides on a slippery table 19.6 and 10.5 (4.1 and 3.6).
            gain: 1500.0,
            damping: 50.0,
            // Concealed recordings (slippery table, kinetic friction 0.03; replayed at 160 x 90),
            // mean tracking error of the struck box (mm), tilt | drag | weight | tether | heavy
            // (box / box2 / box3): the scenes' former own 500 / 40 1.46 | 1.50 | 1.34 | 1.46 |
            // 1.33 / 0.99 / 1.39; the defaults unscaled 8.81 | 8.31 | 17.21 | 9.43 | 9.88 / 8.46
            // / 11.20 (a limit cycle of a few ticks); scaled by friction / 0.09 (500 / 50) 1.48 |
            // 1.51 | 1.40 | 1.49 | 1.35 / 0.95 / 1.41, and all seven concealed rows pass. Scaled
            // by friction / 0.1 with the damping as its square root (450 / 27, the same damping
            // ratio) tracked as well but lost concealed_heavy's diagnosis (named none). pegs's
            // scenario tables (0.4), MuJoCo's model-error recordings (0.12-0.60) and the real
            // T-block (0.15) are above 0.09: unchanged.
            slippery_friction: 0.09,
            slippery_floor: 0.2,
            // The real T-block's model keeps half its velocity a tick (its import's damping,
            // against real images' noise), silhouette IoU per camera: the defaults unscaled
            // 0.7958 / 0.7690 / 0.3230; scaled (2970 / 50) 0.7973 / 0.8032 / 0.3294; its
            // import's former own 5800 / 24 at lr 0.0007 0.7976 / 0.7995 / 0.3275; 2970 with
            // damping 99 0.7963 / 0.7954 / 0.3276, with 29.5 0.7988 / 0.7972 / 0.3300. Every
            // other scene keeps 0.99: unchanged.
            reference_damping: 0.99,
            integral: 0.0,
            integral_leak: 2.0,
            weight_by_gradient: false,
            rope_inertia: 2.0,
            min_displacement: 1e-4,
            pose_search_radius: 0.04,
            pose_search_ring: 0.0,
            pose_search_depth: 0.01,
            pose_search_ring_by_depth: false,
            // MuJoCo model-error recordings, seeds 0-2 (tuning), mean error of 24 objects: 600 /
            // 40 / 3000 left a T-block on a sticky table oscillating (16.9 mm); 300 / 30 / 1500
            // held it (3.4 mm) and the rest alike. 1500 / 50 (the Gaussians' gain) diverged: a
            // whole offset measured once a tick and a tick late takes a softer loop than
            // Adam's bounded steps.
            pose_gain: 300.0,
            // Through the physics's 20 substeps the pull's loop keeps 1.014 of its slowest mode a
            // tick at this damping, where nothing else damps it (`pull` tests): only the table's
            // friction settles it. 25 (0.82 a tick, the least) tracked MuJoCo's fresh seeds
            // better but failed concealed_weight's bar (README, "The pull's own loop"); the
            // follow damping below damps the loop instead.
            pose_damping: 10.0,
            pose_integral: 1500.0,
            // Picked on the sticky and still recordings (63 objects: mean 1.68 mm at 0, 1.59 at
            // 15), then measured on MuJoCo's model-error sets (README, "The follow damping").
            pose_follow_damping: 15.0,
            pose_follow_smoothing: 0.3,
            // MuJoCo model-error recordings 400-402 (24 objects), mean mm / under 5 mm / p95 of
            // 10 mm or more, and pegs's rows (resting box, pushed T-block, two boxes, hidden box,
            // concealed tilt and weight), mean mm: searched under 0.9 with the pull in full,
            // 3.07 / 20 / 5 and 2.68; every object searched (1.01) and the pull in full, 2.67 /
            // 22 / 3 and 2.81 (two_boxes 0.78 -> 1.94); in full under 0.9, 2.61 / 22 / 3 and
            // 2.45; under 0.95, 2.47 / 22 / 3 and 2.18 (hidden box 10.76 -> 7.12, the rest
            // within 0.14 mm). But pegs's concealed diagnosis then missed its bars on two rows
            // (concealed_patch's friction 0.197 against 0.15, 31 %; concealed_weight's 1 s error
            // 12.8 -> 7.0 mm, not halved): the sixth of the pull left at full agreement moves
            // the tracked states open-loop predictions start from. With none there (1.0): 2.56 /
            // 22 / 2 and 2.61 (hidden box 10.17), both rows pass (0.176; 11.5 -> 5.7 mm).
            pose_search_below: 1.0,
            pose_pull_full_below: 0.95,
            // MuJoCo model-error recordings, mean error of 24 objects, objects under 5 mm: dead
            // zone 5 mm -> 4.05 mm, 15; 3 mm -> 3.44, 21; 2 mm -> 3.76, 18; 1 mm -> 3.88, 18 (seeds
            // 300-302, tuning). Fresh seeds 400-402: 5 mm -> 3.40, 17; 3 mm -> 2.91, 21. Under
            // 5 mm, an object held 5-10 mm off at rest by the model's friction (a slippery table's
            // T-block, 9.5 mm for 3 s) was pulled too little to break free. pegs's scenario rows
            // and the concealed recordings moved by at most 0.24 mm (the hidden box, 10.65 ->
            // 10.89), the real T-block's IoU by at most 0.004.
            pose_dead_zone: 0.003,
            // On issue 25's model errors (MuJoCo seeds 2300-2305, 2400-2403, 2500-2503, 112
            // objects; the settings were chosen on earlier seeds): objects meeting its bar
            // (mean under 5 mm, p95 under 10) 93 -> 99, p95 >= 10 mm 18 -> 9, the controls as
            // before. README: "On by default" under "When the model is wrong".
            pose_nudge: 0.5,
            pose_nudge_velocity: 0.5,
            pose_nudge_beyond: 0.006,
            // On issue 25's model errors (MuJoCo seeds 4900-4903, recorded after 0 was the default;
            // 32 objects): objects meeting its bar 20 -> 29, the controls as before. README: "The
            // nudge in contact, on by default".
            pose_nudge_contact_beyond: 0.01,
            max_image_age: 0.07,
            use_roi: true,
            roi_margin_px: 12.0,
            occluder_threshold: 0.0,
            friction_compensation: 0.0,
            friction_ramp: 1.0,
            friction_hold: 0.001,
        }
    }
}

impl CorrectConfig {
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("lr_mean", self.lr_mean),
            ("lr_rotation", self.lr_rotation),
            ("lr_colour", self.lr_colour),
            ("lr_opacity", self.lr_opacity),
            ("noise_floor", self.noise_floor),
            ("gain", self.gain),
            ("damping", self.damping),
            ("integral", self.integral),
            ("integral_leak", self.integral_leak),
            ("min_displacement", self.min_displacement),
            ("max_image_age", self.max_image_age),
            ("pose_search_radius", self.pose_search_radius),
            ("pose_search_ring", self.pose_search_ring),
            ("pose_search_depth", self.pose_search_depth),
            ("pose_gain", self.pose_gain),
            ("pose_damping", self.pose_damping),
            ("pose_integral", self.pose_integral),
            ("pose_follow_damping", self.pose_follow_damping),
            ("pose_dead_zone", self.pose_dead_zone),
            ("pose_search_below", self.pose_search_below),
            ("pose_pull_full_below", self.pose_pull_full_below),
            ("pose_nudge", self.pose_nudge),
            ("pose_nudge_velocity", self.pose_nudge_velocity),
            ("pose_nudge_beyond", self.pose_nudge_beyond),
            ("pose_nudge_contact_beyond", self.pose_nudge_contact_beyond),
            ("roi_margin_px", self.roi_margin_px),
            ("occluder_threshold", self.occluder_threshold),
            ("friction_compensation", self.friction_compensation),
            ("friction_ramp", self.friction_ramp),
            ("friction_hold", self.friction_hold),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                bail!("correct.{name} must be finite and >= 0, got {v}");
            }
        }
        if !(self.slippery_friction.is_finite() && self.slippery_friction > 0.0) {
            bail!(
                "correct.slippery_friction must be finite and > 0, got {}",
                self.slippery_friction
            );
        }
        for (name, v) in [
            ("pose_nudge", self.pose_nudge),
            ("pose_nudge_velocity", self.pose_nudge_velocity),
        ] {
            if v > 1.0 {
                bail!("correct.{name} is a share: set it between 0 and 1 (got {v})");
            }
        }
        for (name, v) in [
            ("slippery_floor", self.slippery_floor),
            ("reference_damping", self.reference_damping),
            ("pose_follow_smoothing", self.pose_follow_smoothing),
        ] {
            if !(v > 0.0 && v <= 1.0) {
                bail!("correct.{name} must be in (0, 1], got {v}");
            }
        }
        if !self.rope_inertia.is_finite() || self.rope_inertia <= 0.0 {
            bail!(
                "correct.rope_inertia must be > 0, got {}",
                self.rope_inertia
            );
        }
        if !(0.0..1.0).contains(&self.beta1)
            || !(0.0..1.0).contains(&self.beta2)
            || self.epsilon.is_nan()
            || self.epsilon <= 0.0
        {
            bail!("correct.beta1 and beta2 must be in [0, 1) and epsilon > 0");
        }
        Ok(())
    }
}

/// One camera's view at the current tick: its calibration and full colour image (row-major,
/// linear RGB in [0, 1]).
pub struct View<'a> {
    pub camera: Camera,
    pub image: &'a [Vec3],
    /// Depth aligned to `image` (m, 0 unknown), where the camera sends one with it: the pose
    /// search scores it too (`CorrectConfig::pose_search_depth`).
    pub depth: Option<&'a [f32]>,
}

/// What one correction did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct CorrectStats {
    /// Photometric loss (mean squared error over the windows, summed over cameras): each camera's
    /// at its first render in the tick (before any update when every iteration renders every
    /// camera), and the sum over the cameras of the last iteration, at its start (a render after
    /// the last update would cost a forward pass and change nothing the tick does).
    pub loss_before: f32,
    pub loss_last: f32,
    /// Pixels left out as unexplained occluders (summed over the windows).
    pub occluded_pixels: usize,
    /// Gaussians whose displacement exceeded the threshold and produced a force.
    pub displaced: usize,
    /// Total visual force per shape (N), indexed by shape id.
    pub force: Vec<Vec3>,
    /// Total visual torque per shape about its centroid (N m), indexed by shape id.
    pub torque: Vec<Vec3>,
    /// Per shape: the silhouette agreement in the tick's first camera before any update
    /// (`agreement`), with its depth where it sends one: what tells a lost track (`tracker`).
    /// None where it shows too little of the object.
    pub agreement: Vec<Option<f32>>,
    /// The same by colour alone: what sets the pose pull's share (`pull_share`; why, at
    /// `agreement::Agreement`).
    pub agreement_colour: Vec<Option<f32>>,
    /// Per shape: how far (m, its particles' mean move) the local search found the object
    /// convincingly off the model's pose (`pull::convincing`) before this tick's nudge; None where
    /// the search did not run or found nothing convincing.
    pub found_offset: Vec<Option<f32>>,
    /// Objects nudged while the model had them touching the robot or another object
    /// (`CorrectConfig::pose_nudge_contact_beyond`), with the speed (m/s) of each one's fastest
    /// particle after the nudge: the physics is to settle them (`Solver::settle_below`).
    pub nudged_in_contact: Vec<(ShapeId, f32)>,
    /// Milliseconds per stage: `setup` (windows, crops, occluder weights), `forward`,
    /// `backward`, `gather` (gradients to the free Gaussians), `adam`, `forces`, and the
    /// renderer's own stages (`render.project`, ...) where it measures them.
    pub stage_ms: std::collections::BTreeMap<String, f64>,
}

/// Add the time since `clock` to `stage` of `stats` and restart the clock.
fn lap(stats: &mut CorrectStats, stage: &str, clock: &mut std::time::Instant) {
    let now = std::time::Instant::now();
    *stats.stage_ms.entry(stage.to_string()).or_insert(0.0) += (now - *clock).as_secs_f64() * 1e3;
    *clock = now;
}

pub struct Corrector {
    pub config: CorrectConfig,
    renderer: Box<dyn Renderer + Send>,
    adam: [Adam; 4],
    /// Each Gaussian's displacement across ticks (derivative and integral terms).
    displacements: Vec<DisplacementState>,
    /// Each particle's pose pull across ticks (`PullState`).
    pulls: Vec<PullState>,
    /// Per shape: whether the predict step before this correction had it touch the robot or
    /// another object (`note_contacts`); such an object is nudged only far off
    /// (`CorrectConfig::pose_nudge_contact_beyond`).
    in_contact: Vec<bool>,
    /// The inverse masses the physics integrates the forces with (`note_masses`); empty: the
    /// world's own.
    integrated_inv_mass: Vec<f32>,
    /// Each particle's push and turn along the table, averaged over ticks (`compensate_friction`).
    pushes: FrictionMemory,
    /// Each shape's silhouette agreement, averaged over ticks (`AGREEMENT_SMOOTHING`).
    agreement_avg: Vec<f32>,
    /// Per shape, which of its Gaussians' depth the pose search scores
    /// (`relocate::depth_trusted`, taken the first time it has depth); None: not yet.
    depth_trusted: Vec<Option<Vec<bool>>>,
    /// Per shape, whether last tick's search found it convincingly beyond
    /// `pose_nudge_contact_beyond` (`nudge::found_beyond`): an object in contact is nudged only
    /// the second tick running.
    found_far: Vec<bool>,
    /// Per shape, the pose the local search found last tick (`relocate::Corrector::local_poses`
    /// searches around it as well as around the model's); None: none yet, or forgotten.
    last_found: Vec<Option<crate::math::Pose>>,
    /// The camera the next iteration starts with (`cameras_per_iteration` > 0).
    turn: usize,
    /// The static scene rendered into each camera seen so far (`SceneRender`).
    backgrounds: Vec<SceneRender>,
    /// What each camera of the first correction saw where the model has nothing
    /// (`backdrop::Backdrop`), and whether they were taken.
    backdrops: Vec<Backdrop>,
    backdrops_taken: bool,
    /// The table the objects rest on, as the model has it (`friction_compensation`).
    support: Option<Support>,
    /// The model's physics the gain is scaled for (`loop_gains`).
    plant: Plant,
}

impl Corrector {
    pub fn new(config: CorrectConfig, render: RenderSettings) -> Result<Self> {
        config.validate()?;
        let renderer = render::open(config.backend, render)?;
        let a = Adam::new(config.beta1, config.beta2, config.epsilon)
            .with_noise_floor(config.noise_floor);
        let means = a
            .clone()
            .grouped(if config.isotropic_means { 3 } else { 1 });
        Ok(Self {
            config,
            renderer,
            adam: [means, a.clone(), a.clone(), a],
            displacements: Vec::new(),
            pulls: Vec::new(),
            in_contact: Vec::new(),
            integrated_inv_mass: Vec::new(),
            pushes: FrictionMemory::default(),
            agreement_avg: Vec::new(),
            depth_trusted: Vec::new(),
            found_far: Vec::new(),
            last_found: Vec::new(),
            turn: 0,
            backgrounds: Vec::new(),
            backdrops: Vec::new(),
            backdrops_taken: false,
            support: None,
            plant: Plant::default(),
        })
    }

    /// The table the model's objects rest on (friction compensation needs it).
    pub fn with_support(mut self, support: Option<Support>) -> Self {
        self.support = support;
        self
    }

    /// The model the visual forces push: its table's friction and velocity damping scale the
    /// configured gain (`plant::loop_gains`). Default: pegs's default physics.
    pub fn with_plant(mut self, plant: Plant) -> Self {
        self.plant = plant;
        self
    }

    /// The contacts of the predict step before this tick's correction, per shape: an object the
    /// model pushes with the robot or another object moves as the model's contact says, and a
    /// nudge would put it into what pushes it (`nudge`).
    pub fn note_contacts(&mut self, touched: &[crate::physics::Touched]) {
        self.in_contact.clear();
        self.in_contact
            .extend(touched.iter().map(|t| t.kinematic || t.dynamic));
    }

    /// The inverse masses the physics integrates the next forces with (`Solver::inv_mass`: the
    /// world's with the model's mass effects, such as a hidden weight), so that the forces move
    /// each body as the images ask whatever the model says of its mass (`spread`).
    pub fn note_masses(&mut self, inv_mass: &[f32]) {
        self.integrated_inv_mass.clear();
        self.integrated_inv_mass.extend_from_slice(inv_mass);
    }

    /// The gain (1/s^2) the visual forces take on this model (`plant::loop_gains`).
    pub fn gain(&self) -> f32 {
        loop_gains(&self.config, &self.plant).0
    }

    /// Optimise the tracked objects' Gaussians against `views` and add the resulting visual
    /// forces to the world's particles (they act in the next predict step). `dt` is the tick.
    pub fn correct(&mut self, world: &mut World, views: &[View], dt: f32) -> Result<CorrectStats> {
        let mut clock = std::time::Instant::now();
        let mut stats = CorrectStats {
            force: vec![Vec3::ZERO; world.shapes.len()],
            torque: vec![Vec3::ZERO; world.shapes.len()],
            ..Default::default()
        };
        let mut cloud = GaussianCloud::from_world(world);
        // Free: Gaussians bonded to particles of dynamic objects. Robot and scene only occlude.
        let free: Vec<usize> = (0..cloud.len())
            .filter(|&i| {
                let p = world.gaussians.parent[i];
                p != NO_PARENT
                    && matches!(
                        world.shapes.kind[world.particles.shape[p as usize] as usize],
                        ShapeKind::Rigid | ShapeKind::Rope
                    )
            })
            .collect();
        if free.is_empty() || views.is_empty() {
            return Ok(stats);
        }
        for v in views {
            if v.image.len() != (v.camera.width * v.camera.height) as usize {
                bail!(
                    "image of {} pixels for a {}x{} camera",
                    v.image.len(),
                    v.camera.width,
                    v.camera.height
                );
            }
        }
        if !self.backdrops_taken {
            self.take_backdrops(world, views)?;
        }
        let windows: Vec<Roi> = views
            .iter()
            .map(|v| {
                if self.config.use_roi {
                    render::footprint_roi(&cloud, &free, &v.camera, self.config.roi_margin_px)
                } else {
                    Roi::full(&v.camera)
                }
            })
            .collect();
        let targets: Vec<Vec<Vec3>> = views
            .iter()
            .zip(&windows)
            .map(|(v, w)| crop(v.image, v.camera.width, *w))
            .collect();
        let weights: Vec<Vec<f32>> = if self.config.occluder_threshold > 0.0 {
            let mut objects = GaussianCloud::default();
            free.iter().for_each(|&i| objects.push(cloud.get(i)));
            let threshold = self.config.occluder_threshold;
            let mut weights = Vec::with_capacity(views.len());
            for ((v, w), target) in views.iter().zip(&windows).zip(&targets) {
                if w.pixels() == 0 {
                    weights.push(Vec::new());
                    continue;
                }
                // What the objects look like here, as rendered (single Gaussians can be outliers).
                let rendered = self.renderer.forward(&objects, &v.camera, *w)?;
                let palette = rendered_palette(&rendered.colour, &rendered.alpha);
                let background = crop(self.background(world, &v.camera)?, v.camera.width, *w);
                let wv: Vec<f32> = target
                    .iter()
                    .zip(&background)
                    .map(|(o, b)| {
                        if explained(*o, *b, &palette, threshold) {
                            1.0
                        } else {
                            0.0
                        }
                    })
                    .collect();
                stats.occluded_pixels += wv.iter().filter(|x| **x == 0.0).count();
                weights.push(wv);
            }
            weights
        } else {
            targets.iter().map(|t| vec![1.0; t.len()]).collect()
        };
        let n = free.len();
        let start: Vec<Vec3> = free.iter().map(|&i| cloud.mean[i]).collect();
        let mut means: Vec<f32> = start.iter().flat_map(|m| m.to_array()).collect();
        let mut rots: Vec<f32> = free
            .iter()
            .flat_map(|&i| cloud.rotation[i].to_array())
            .collect();
        let mut cols: Vec<f32> = free
            .iter()
            .flat_map(|&i| cloud.colour[i].to_array())
            .collect();
        let mut ops: Vec<f32> = free.iter().map(|&i| cloud.opacity_logit[i]).collect();
        for (a, len) in self.adam.iter_mut().zip([3 * n, 4 * n, 3 * n, n]) {
            a.reset(len);
        }
        // The gain and damping this model takes (its table's friction and velocity damping).
        let mut c = self.config.clone();
        (c.gain, c.damping) = loop_gains(&self.config, &self.plant);
        let per_iteration = match c.cameras_per_iteration as usize {
            0 => views.len(),
            k => k.min(views.len()),
        };
        let mut rendered = vec![false; views.len()];
        self.renderer.take_stage_ms();
        lap(&mut stats, "setup", &mut clock);
        for it in 0..c.iterations {
            for (k, &i) in free.iter().enumerate() {
                cloud.mean[i] = Vec3::from_slice(&means[3 * k..]);
                cloud.rotation[i] = Vec4::from_slice(&rots[4 * k..]);
                cloud.colour[i] = Vec3::from_slice(&cols[3 * k..]);
                cloud.opacity_logit[i] = ops[k];
            }
            let (mut gm, mut gr, mut gc, mut go) = (
                vec![0.0f32; 3 * n],
                vec![0.0f32; 4 * n],
                vec![0.0f32; 3 * n],
                vec![0.0f32; n],
            );
            let mut loss = 0.0f32;
            for j in 0..per_iteration {
                let v = (self.turn + it as usize * per_iteration + j) % views.len();
                let (view, window, target, weight) =
                    (&views[v], &windows[v], &targets[v], &weights[v]);
                if window.pixels() == 0 {
                    continue;
                }
                // The static scene alone, for the silhouette agreement of the tick's first view
                // (rendered before the view: the renderer keeps the last forward for backward).
                let behind = match it == 0 && j == 0 {
                    true => {
                        let width = view.camera.width;
                        let (colour, coverage) = self.background_render(world, &view.camera)?;
                        Some((crop(colour, width, *window), crop(coverage, width, *window)))
                    }
                    false => None,
                };
                let out = self.renderer.forward(&cloud, &view.camera, *window)?;
                lap(&mut stats, "forward", &mut clock);
                let scale = 1.0 / (3.0 * window.pixels() as f32);
                let camera_loss = out
                    .colour
                    .iter()
                    .zip(target)
                    .zip(weight)
                    .map(|((a, b), w)| w * (*a - *b).length_squared())
                    .sum::<f32>()
                    * scale;
                loss += camera_loss;
                if let Some((behind, coverage)) = &behind {
                    let measured = depth_in_window(view, *window, c.pose_search_depth);
                    let pixels = agreement::WindowPixels {
                        rendered: &out.colour,
                        background: behind,
                        coverage,
                        observed: target,
                        depth: measured.as_deref().map(|measured| agreement::DepthPixels {
                            measured,
                            rendered_depth: &out.depth,
                            alpha: &out.alpha,
                            tolerance: c.pose_search_depth,
                        }),
                    };
                    let seen = (&view.camera, *window);
                    let agreement::Agreement { with_depth, colour } =
                        agreement::silhouette_agreement(world, &cloud, &free, seen, &pixels);
                    (stats.agreement, stats.agreement_colour) = (with_depth, colour);
                }
                if !rendered[v] {
                    rendered[v] = true;
                    stats.loss_before += camera_loss;
                }
                let d = PixelGrads {
                    colour: out
                        .colour
                        .iter()
                        .zip(target)
                        .zip(weight)
                        .map(|((a, b), w)| 2.0 * scale * w * (*a - *b))
                        .collect(),
                    ..Default::default()
                };
                let g = self.renderer.backward(&cloud, &d)?;
                lap(&mut stats, "backward", &mut clock);
                for (k, &i) in free.iter().enumerate() {
                    for j in 0..3 {
                        gm[3 * k + j] += g.mean[i][j];
                        gc[3 * k + j] += g.colour[i][j];
                    }
                    for j in 0..4 {
                        gr[4 * k + j] += g.rotation[i][j];
                    }
                    go[k] += g.opacity_logit[i];
                }
                lap(&mut stats, "gather", &mut clock);
            }
            stats.loss_last = loss;
            self.adam[0].step(&mut means, &gm, c.lr_mean);
            if c.lr_rotation > 0.0 {
                self.adam[1].step(&mut rots, &gr, c.lr_rotation);
            }
            if c.lr_colour > 0.0 {
                self.adam[2].step(&mut cols, &gc, c.lr_colour);
            }
            if c.lr_opacity > 0.0 {
                self.adam[3].step(&mut ops, &go, c.lr_opacity);
            }
            lap(&mut stats, "adam", &mut clock);
        }
        self.turn = (self.turn + c.iterations as usize * per_iteration) % views.len();
        for (stage, ms) in self.renderer.take_stage_ms() {
            stats.stage_ms.insert(format!("render.{stage}"), ms);
        }
        // Displacements become forces on the parent particles.
        if self.displacements.len() != cloud.len() {
            self.displacements = vec![DisplacementState::default(); cloud.len()];
        }
        let mut forces = vec![Vec3::ZERO; world.particles.len()];
        // A particle's force follows the mean displacement of its Gaussians, so densifying the
        // appearance (more Gaussians per particle) does not scale the forces up.
        let centroids: Vec<Vec3> = (0..world.shapes.len() as u32)
            .map(|s| world.shape_centroid(s))
            .collect();
        let mut bonded = vec![0u32; world.particles.len()];
        for &i in &free {
            bonded[world.gaussians.parent[i] as usize] += 1;
        }
        let force_mass = force_mass(world, &bonded, c.rope_inertia);
        let weight = c
            .weight_by_gradient
            .then(|| gradient_weights(world, &free, &self.adam[0].rms(3 * n)));
        for (k, &i) in free.iter().enumerate() {
            let mut d = Vec3::from_slice(&means[3 * k..]) - start[k];
            if !d.is_finite() || d.length() < c.min_displacement {
                d = Vec3::ZERO;
            }
            let accel = self.displacements[i].acceleration(d, &c, dt);
            if d != Vec3::ZERO {
                stats.displaced += 1;
            }
            if accel == Vec3::ZERO {
                continue;
            }
            let p = world.gaussians.parent[i] as usize;
            let w = weight.as_ref().map_or(1.0, |w| w[k]);
            let f = force_mass[p] * w * accel / bonded[p].max(1) as f32;
            forces[p] += f;
            let shape = world.particles.shape[p];
            stats.force[shape as usize] += f;
            stats.torque[shape as usize] +=
                (world.particles.position[p] - centroids[shape as usize]).cross(f);
        }
        if c.pose_search_radius > 0.0 {
            // One camera a tick measures the agreement: average over the last few.
            self.agreement_avg.resize(world.shapes.len(), 1.0);
            for (avg, a) in self.agreement_avg.iter_mut().zip(&stats.agreement_colour) {
                if let Some(a) = a {
                    *avg += AGREEMENT_SMOOTHING * (a - *avg);
                }
            }
            let wanted: Vec<bool> = self
                .agreement_avg
                .iter()
                .map(|a| *a < c.pose_search_below)
                .collect();
            let poses = self.local_poses(world, views, c.pose_search_radius, &wanted)?;
            lap(&mut stats, "pose_search", &mut clock);
            stats.found_offset = pull::found_offsets(world, &poses);
            let shares: Vec<f32> = self
                .agreement_avg
                .iter()
                .map(|a| pull_share(*a, &c))
                .collect();
            // Where the model's own contact pushes an object, it moves as the contact says: it is
            // nudged only far off, found so two ticks running, and settled (`nudge`).
            let convincing: Vec<_> = poses.iter().map(|p| p.filter(pull::convincing)).collect();
            let far = nudge::found_beyond(world, &convincing, c.pose_nudge_contact_beyond);
            let before = std::mem::replace(&mut self.found_far, far);
            let contact = (&self.in_contact[..], &before[..]);
            for n in nudge::nudge_towards_found(world, &convincing, &shares, contact, &c, dt) {
                stats.force[n.shape as usize] += n.force;
                if let Some(speed) = n.settle_below {
                    stats.nudged_in_contact.push((n.shape, speed));
                }
            }
            let mut pulls = pose_pulls(world, &poses, c.pose_dead_zone);
            for (d, shape) in pulls.iter_mut().zip(&world.particles.shape) {
                if let Some(d) = d {
                    *d *= shares[*shape as usize];
                }
            }
            self.pulls.resize(pulls.len(), PullState::default());
            for (i, (d, state)) in pulls.iter().zip(&mut self.pulls).enumerate() {
                let share = shares[world.particles.shape[i] as usize];
                let (position, velocity) =
                    (world.particles.position[i], world.particles.velocity[i]);
                let accel = state.acceleration_following(*d, position, velocity, share, &c, dt);
                if accel == Vec3::ZERO || world.particles.inv_mass[i] <= 0.0 {
                    continue;
                }
                let f = accel / world.particles.inv_mass[i];
                forces[i] += f;
                let shape = world.particles.shape[i] as usize;
                stats.force[shape] += f;
                stats.torque[shape] += (world.particles.position[i] - centroids[shape]).cross(f);
            }
        }
        if let Some(support) = self.support.filter(|_| c.friction_compensation > 0.0) {
            compensate_friction(world, &mut forces, &mut self.pushes, &support, &c);
        }
        let integrated = match self.integrated_inv_mass.len() == world.particles.len() {
            true => &self.integrated_inv_mass,
            false => &world.particles.inv_mass,
        };
        spread_over_rigid_bodies(world, integrated, &mut forces);
        spread_along_ropes(world, &mut forces, ROPE_SPREAD);
        for (ext, f) in world.particles.external_force.iter_mut().zip(&forces) {
            *ext += *f;
        }
        lap(&mut stats, "forces", &mut clock);
        Ok(stats)
    }
}

impl Corrector {
    /// Forget what the visual forces measured of `shape` before it was moved (relocated): the
    /// forces this tick put on its particles, its Gaussians' displacement history and its pose
    /// pulls were all measured against the pose it no longer has. Kept, they throw the object
    /// from where the images show it back towards where the model had it (MuJoCo's
    /// control_pushed_300: 40 mm within 0.1 s of each relocation).
    pub fn forget(&mut self, world: &mut World, shape: ShapeId) {
        for i in world.shapes.range(shape) {
            world.particles.external_force[i] = Vec3::ZERO;
            if let Some(pull) = self.pulls.get_mut(i) {
                *pull = PullState::default();
            }
            self.pushes.forget(i);
        }
        if let Some(found) = self.last_found.get_mut(shape as usize) {
            *found = None;
        }
        if let Some(far) = self.found_far.get_mut(shape as usize) {
            *far = false;
        }
        for g in world.gaussians_of(shape) {
            if let Some(d) = self.displacements.get_mut(g) {
                *d = DisplacementState::default();
            }
        }
    }
}

/// Static-scene renders kept (`Corrector::background`): every fixed camera of a rig, while a camera
/// that moves does not grow the cache without bound.
const MAX_BACKGROUNDS: usize = 16;

/// The static scene (Gaussians without a parent) rendered into one camera: its colour and coverage
/// (accumulated alpha, 1 where the static scene fills the pixel), and both with the camera's
/// backdrop where it has one (`Backdrop::merged`), which the agreement and the pose search compare
/// with.
struct SceneRender {
    camera: Camera,
    colour: Vec<Vec3>,
    coverage: Vec<f32>,
    with_backdrop: Option<(Vec<Vec3>, Vec<f32>)>,
}

impl SceneRender {
    /// The colour and coverage an object's pixels are compared with
    /// (`Corrector::background_render`).
    fn compared(&self) -> (&[Vec3], &[f32]) {
        match &self.with_backdrop {
            Some((colour, coverage)) => (colour, coverage),
            None => (&self.colour, &self.coverage),
        }
    }
}

impl Corrector {
    /// The static scene rendered into `camera` (colour only, without the backdrop: the occluder
    /// test compares what the model renders), cached per camera.
    fn background(&mut self, world: &World, camera: &Camera) -> Result<&[Vec3]> {
        let k = self.scene_render(world, camera)?;
        Ok(&self.backgrounds[k].colour)
    }

    /// What the agreement and the pose search compare an object's pixels with in `camera`: the
    /// static scene's colour and coverage (1 where it fills the pixel, 0 where the model has
    /// nothing there), with the backdrop where the camera has one.
    fn background_render(&mut self, world: &World, camera: &Camera) -> Result<(&[Vec3], &[f32])> {
        let k = self.scene_render(world, camera)?;
        Ok(self.backgrounds[k].compared())
    }

    /// The index in the cache of `camera`'s static-scene render (rendered where missing; the
    /// newest `MAX_BACKGROUNDS` poses are kept: a camera moved by tf has a new pose every tick).
    fn scene_render(&mut self, world: &World, camera: &Camera) -> Result<usize> {
        if let Some(k) = self.backgrounds.iter().position(|r| r.camera == *camera) {
            return Ok(k);
        }
        let out = self.renderer.forward(
            &GaussianCloud::static_scene(world),
            camera,
            Roi::full(camera),
        )?;
        let with_backdrop = (self.backdrops.iter())
            .find(|b| b.camera == *camera)
            .map(|b| b.merged(&out.colour, &out.alpha));
        if self.backgrounds.len() >= MAX_BACKGROUNDS {
            self.backgrounds.remove(0);
        }
        self.backgrounds.push(SceneRender {
            camera: *camera,
            colour: out.colour,
            coverage: out.alpha,
            with_backdrop,
        });
        Ok(self.backgrounds.len() - 1)
    }

    /// Take each view's backdrop (`backdrop::Backdrop`), once: at the first correction with views.
    fn take_backdrops(&mut self, world: &World, views: &[View]) -> Result<()> {
        self.backdrops_taken = true;
        for v in views.iter().take(MAX_BACKGROUNDS) {
            let k = self.scene_render(world, &v.camera)?;
            let r = &mut self.backgrounds[k];
            let taken =
                Backdrop::take(&mut *self.renderer, world, &v.camera, v.image, &r.coverage)?;
            r.with_backdrop = Some(taken.merged(&r.colour, &r.coverage));
            self.backdrops.push(taken);
        }
        Ok(())
    }
}

/// Whether the model explains an observed pixel colour: close (RGB distance within `threshold`) to
/// the static scene rendered there (`background`), or the same surface as one of the colours the
/// tracked objects render with (`palette`, see `same_surface`). Unexplained pixels show something
/// the model does not have in front of it.
pub fn explained(observed: Vec3, background: Vec3, palette: &[Vec3], threshold: f32) -> bool {
    observed.distance(background) <= threshold
        || palette
            .iter()
            .any(|c| same_surface(observed, *c, threshold))
}

/// The colours the Gaussians of a render cover (alpha > 0.5, un-premultiplied) with at least 1 % of
/// those pixels (see `palette`).
pub fn rendered_palette(colour: &[Vec3], alpha: &[f32]) -> Vec<Vec3> {
    palette(
        colour
            .iter()
            .zip(alpha)
            .filter(|(_, a)| **a > 0.5)
            .map(|(c, a)| *c / *a),
        0.01,
    )
}

/// Whether `observed` can be the surface of colour `model` under other light: its brightness
/// within a factor of 2.5 of the model's (or both dark) and its chromaticity within `threshold`
/// (the distance of `observed` from the line through `model`).
pub fn same_surface(observed: Vec3, model: Vec3, threshold: f32) -> bool {
    const DARK: f32 = 0.15;
    let (lo, lm) = (observed.length(), model.length());
    if lo < DARK && lm < DARK {
        return true;
    }
    let Some(axis) = model.try_normalize() else {
        return false;
    };
    let along = observed.dot(axis);
    let ratio = along / lm.max(1e-6);
    (0.4..=2.5).contains(&ratio) && (observed - along * axis).length() <= threshold
}

/// The colours of a set (quantised to 1/20) that make up at least `min_share` of it.
pub fn palette(colours: impl Iterator<Item = Vec3>, min_share: f32) -> Vec<Vec3> {
    let mut bins: std::collections::BTreeMap<[i32; 3], (Vec3, usize)> =
        std::collections::BTreeMap::new();
    let mut total = 0usize;
    for c in colours {
        let key = (c.clamp(Vec3::ZERO, Vec3::ONE) * 20.0)
            .round()
            .as_ivec3()
            .to_array();
        let bin = bins.entry(key).or_insert((Vec3::ZERO, 0));
        bin.0 += c;
        bin.1 += 1;
        total += 1;
    }
    bins.into_values()
        .filter(|(_, n)| *n as f32 >= min_share * total as f32)
        .map(|(sum, n)| sum / n as f32)
        .collect()
}

/// Each particle's force mass (kg): the mass by which the gain times its Gaussians' mean
/// displacement becomes a force. A rope particle's is its own mass divided by `rope_inertia`, so
/// it accelerates at `gain x displacement / rope_inertia`. A rigid body's particles with
/// Gaussians share the whole body's mass in proportion to their own, so a body whose Gaussians
/// all moved by `d` accelerates at `gain x d`, whatever its mass, its number of particles and how
/// many of them lie inside, unseen.
pub fn force_mass(world: &World, bonded: &[u32], rope_inertia: f32) -> Vec<f32> {
    let p = &world.particles;
    let mass = |i: usize| p.movable_mass(i);
    let mut scale: Vec<f32> = (0..p.len()).map(mass).collect();
    for s in 0..world.shapes.len() {
        let range = world.shapes.range(s as u32);
        if world.shapes.kind[s] == ShapeKind::Rope {
            range.for_each(|i| scale[i] /= rope_inertia);
            continue;
        }
        if world.shapes.kind[s] != ShapeKind::Rigid {
            continue;
        }
        let whole: f32 = range.clone().map(mass).sum();
        let seen: f32 = range.clone().filter(|&i| bonded[i] > 0).map(mass).sum();
        if seen > 0.0 {
            range.for_each(|i| scale[i] *= whole / seen);
        }
    }
    scale
}

/// Weight of a tick's agreement in its running average (about the last three ticks).
const AGREEMENT_SMOOTHING: f32 = 0.4;

/// Most a Gaussian counts under `CorrectConfig::weight_by_gradient`, in multiples of its object's
/// mean: the gain on the few Gaussians of an object barely in view (the rest hidden, with no
/// gradient) grows by at most this much.
pub const MAX_GRADIENT_WEIGHT: f32 = 3.0;

/// Per free Gaussian (`free[k]`), its RMS gradient `rms[k]` over the mean of its rigid object's
/// seen Gaussians (those with any gradient), at most `MAX_GRADIENT_WEIGHT` (1 where the object's
/// are all zero, and for rope Gaussians). The weights move the push among the Gaussians in view;
/// a hidden one (no gradient, so no displacement either) weighs nothing.
pub fn gradient_weights(world: &World, free: &[usize], rms: &[f32]) -> Vec<f32> {
    let shape_of = |i: usize| world.particles.shape[world.gaussians.parent[i] as usize] as usize;
    let mut sum = vec![(0.0f32, 0usize); world.shapes.len()];
    for (k, &i) in free.iter().enumerate().filter(|(k, _)| rms[*k] > 0.0) {
        let s = &mut sum[shape_of(i)];
        s.0 += rms[k];
        s.1 += 1;
    }
    free.iter()
        .enumerate()
        .map(|(k, &i)| {
            let s = shape_of(i);
            let (total, count) = sum[s];
            match world.shapes.kind[s] == ShapeKind::Rigid && total > 0.0 {
                true => (rms[k] * count as f32 / total).min(MAX_GRADIENT_WEIGHT),
                false => 1.0,
            }
        })
        .collect()
}

/// One Gaussian's displacement across ticks: its displacement at the previous tick and its
/// leaky integral (m s).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DisplacementState {
    previous: Vec3,
    integral: Vec3,
}

impl DisplacementState {
    /// The acceleration (m/s^2) this tick's displacement `d` (m; zero when it is too short to
    /// trust) asks of its particle: `gain x d + damping x its change per second` while `d` is
    /// not zero, plus `integral x` the displacement integrated over the ticks, which leaks at
    /// `integral_leak` and so keeps pushing a little after `d` has gone.
    pub fn acceleration(&mut self, d: Vec3, c: &CorrectConfig, dt: f32) -> Vec3 {
        let rate = (d - self.previous) / dt;
        self.previous = d;
        self.integral = self.integral * (1.0 - c.integral_leak * dt).max(0.0) + d * dt;
        let mut accel = c.integral * self.integral;
        if d != Vec3::ZERO {
            accel += c.gain * d + c.damping * rate;
        }
        accel
    }
}

/// The view's depth cropped to `window`, where it sends one of its size and the pose search reads
/// depth (`tolerance` above 0).
fn depth_in_window(view: &View, window: Roi, tolerance: f32) -> Option<Vec<f32>> {
    let (width, height) = (view.camera.width, view.camera.height);
    (view.depth)
        .filter(|d| tolerance > 0.0 && d.len() == width as usize * height as usize)
        .map(|d| crop(d, width, window))
}

fn crop<T: Copy>(image: &[T], width: u32, w: Roi) -> Vec<T> {
    let mut out = Vec::with_capacity(w.pixels());
    for y in w.y0..w.y1 {
        let row = (y * width) as usize;
        out.extend_from_slice(&image[row + w.x0 as usize..row + w.x1 as usize]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Pose;
    use crate::render::cpu::CpuRenderer;
    use crate::world::{WorldBuilder, box_lattice};

    /// One correction of `world` against `image` seen by `camera`, at 30 Hz.
    fn correct_once(
        world: &mut World,
        config: CorrectConfig,
        camera: Camera,
        image: &[Vec3],
    ) -> CorrectStats {
        let mut c = Corrector::new(config, RenderSettings::default()).unwrap();
        c.correct(
            world,
            &[View {
                camera,
                image,
                depth: None,
            }],
            1.0 / 30.0,
        )
        .unwrap()
    }

    /// A square plate of `mass` kg (half side `half`, m) lying at `x` along the x axis, 1 cm
    /// above the ground, its Gaussians set to `look` (scale, opacity) where given.
    fn plate(half: f32, mass: f32, x: f32, look: Option<(f32, f32)>) -> (World, ShapeId) {
        let mut b = WorldBuilder::new();
        let points = box_lattice(Vec3::new(half, half, 0.0), 0.01);
        let n = points.len() as f32;
        let s = b.add_rigid(
            "plate",
            &points,
            0.005,
            mass / n,
            Pose::from_translation(Vec3::new(x, 0.0, 0.01)),
            Vec3::new(0.9, 0.5, 0.1),
        );
        if let Some((scale, opacity)) = look {
            b.set_gaussian_look(s, scale, opacity);
        }
        (b.build(), s)
    }

    /// What `camera` sees of `world`.
    fn image_of(world: &World, camera: &Camera) -> Vec<Vec3> {
        CpuRenderer::new(RenderSettings::default())
            .forward(&GaussianCloud::from_world(world), camera, Roi::full(camera))
            .colour
    }

    #[test]
    fn a_visual_force_accelerates_a_body_alike_whatever_its_mass() {
        // The same plate of 10 g or 50 g, seen 4 mm from where the model has it: the visual
        // force scales with the mass, so the acceleration is the same.
        let camera = Camera::look_at(96, 72, 110.0, Vec3::new(0.0, 0.0, 0.3), Vec3::ZERO);
        let acceleration = |mass: f32| {
            let image = image_of(&plate(0.025, mass, 0.004, None).0, &camera);
            let (mut w, s) = plate(0.025, mass, 0.0, None);
            let stats = correct_once(&mut w, CorrectConfig::default(), camera, &image);
            stats.force[s as usize] / w.shapes.mass[s as usize]
        };
        let (light, heavy) = (acceleration(0.01), acceleration(0.05));
        assert!(light.x > 1.0, "pulled towards the image: {light}");
        assert!(
            (heavy.x / light.x - 1.0).abs() < 0.01,
            "10 g: {light} m/s^2; 50 g: {heavy} m/s^2"
        );
    }

    #[test]
    fn a_relocated_object_keeps_no_force_measured_where_it_was() {
        // A plate seen 6 mm along x from where the model has it: the correction leaves a +x force
        // on its particles for the next predict step. The tracker then moves the plate where the
        // images show it (a relocation): that force would throw it on past them, so the corrector
        // forgets it, and the displacement and pull history measured from the old pose.
        let camera = Camera::look_at(96, 72, 110.0, Vec3::new(0.0, 0.0, 0.3), Vec3::ZERO);
        let image = image_of(&plate(0.025, 0.036, 0.006, None).0, &camera);
        let views = [View {
            camera,
            image: &image,
            depth: None,
        }];
        // The force (N) on the plate that the next predict step would apply after the move.
        let after_move = |forget: bool| {
            let (mut w, s) = plate(0.025, 0.036, 0.0, None);
            let config = CorrectConfig::default();
            let mut c = Corrector::new(config, RenderSettings::default()).unwrap();
            c.correct(&mut w, &views, 1.0 / 30.0).unwrap();
            w.move_shape(s, Pose::from_translation(Vec3::new(0.006, 0.0, 0.0)));
            if forget {
                c.forget(&mut w, s);
                let cleared = c
                    .displacements
                    .iter()
                    .all(|d| *d == DisplacementState::default())
                    && c.pulls.iter().all(|p| *p == PullState::default());
                assert!(cleared, "the history measured from the old pose is dropped");
            }
            w.shapes
                .range(s)
                .map(|i| w.particles.external_force[i])
                .sum::<Vec3>()
        };
        let (kept, forgotten) = (after_move(false), after_move(true));
        assert!(
            kept.x > 0.01,
            "the correction pushed the plate towards the image: {kept}"
        );
        assert_eq!(forgotten, Vec3::ZERO);
    }

    #[test]
    fn gradient_weights_average_one_over_a_rigid_body_and_follow_its_rms_gradients() {
        let (w, _) = plate(0.02, 0.05, 0.0, None);
        let free: Vec<usize> = (0..w.gaussians.len()).collect();
        let rms: Vec<f32> = (0..free.len()).map(|k| 1.0 + (k % 3) as f32).collect();
        let weight = gradient_weights(&w, &free, &rms);
        let mean = weight.iter().sum::<f32>() / weight.len() as f32;
        assert!((mean - 1.0).abs() < 1e-5, "{mean}");
        // rms 3 against rms 1: three times the weight.
        assert!((weight[2] / weight[0] - 3.0).abs() < 1e-5, "{weight:?}");
        let none = gradient_weights(&w, &free, &vec![0.0; free.len()]);
        assert!(
            none.iter().all(|x| *x == 1.0),
            "no gradient anywhere: every Gaussian alike"
        );
    }

    #[test]
    fn a_uniform_body_is_pushed_by_the_edges_that_see_it_under_gradient_weights() {
        // A plate of one colour seen 4 mm along x from where the model has it: only its edges
        // see the offset. Averaged alike, its inside's noise steps dilute the push (here below
        // what static friction 0.5 holds, 4.9 m/s^2); weighted by their gradients, the edges set
        // it, at gain x offset.
        let camera = Camera::look_at(96, 72, 110.0, Vec3::new(0.0, 0.0, 0.3), Vec3::ZERO);
        let look = Some((0.008, 0.99)); // wide, opaque: one even colour inside
        // Sensor noise, +-0.03 per channel (a fixed pseudo-random pattern).
        let noise = |k: usize| ((k as f32 * 12.9898).sin() * 43758.547).fract() * 0.06 - 0.03;
        let image: Vec<Vec3> = image_of(&plate(0.06, 0.169, 0.004, look).0, &camera)
            .iter()
            .enumerate()
            .map(|(k, c)| *c + Vec3::new(noise(3 * k), noise(3 * k + 1), noise(3 * k + 2)))
            .collect();
        let acceleration = |weighted: bool| {
            let (mut w, s) = plate(0.06, 0.169, 0.0, look);
            let config = CorrectConfig {
                weight_by_gradient: weighted,
                damping: 0.0,
                ..Default::default()
            };
            let stats = correct_once(&mut w, config.clone(), camera, &image);
            (stats.force[s as usize] / w.shapes.mass[s as usize], config)
        };
        let ((alike, _), (weighted, c)) = (acceleration(false), acceleration(true));
        eprintln!("alike {alike} m/s^2, weighted {weighted} m/s^2");
        // The law the gain states: pushed at gain x offset (6 m/s^2 here).
        let law = c.gain * 0.004;
        assert!(alike.x > 0.0 && alike.x < 0.5 * law, "diluted: {alike}");
        assert!(
            (weighted.x / law - 1.0).abs() < 0.3,
            "{weighted} against {law}"
        );
        assert!(
            weighted.y.abs() < 0.2 * weighted.x,
            "along the offset: {weighted}"
        );
    }

    #[test]
    fn a_body_seen_through_half_its_particles_lends_them_all_its_mass() {
        let mut b = WorldBuilder::new();
        let s = b.add_rigid(
            "box",
            &box_lattice(Vec3::new(0.02, 0.02, 0.01), 0.01),
            0.005,
            0.002,
            Pose::IDENTITY,
            Vec3::ONE,
        );
        let w = b.build();
        let range = w.shapes.range(s);
        let bonded: Vec<u32> = (0..w.particles.len()).map(|i| (i % 2) as u32).collect();
        let scale = force_mass(&w, &bonded, 2.0);
        let with: f32 = range
            .clone()
            .filter(|&i| bonded[i] > 0)
            .map(|i| scale[i])
            .sum();
        assert!((with - w.shapes.mass[s as usize]).abs() < 1e-6, "{with}");
    }

    #[test]
    fn an_unmodelled_occluder_pushes_the_object_unless_its_pixels_are_left_out() {
        let mut b = WorldBuilder::new();
        b.add_rigid(
            "box",
            &box_lattice(Vec3::new(0.04, 0.03, 0.02), 0.01),
            0.005,
            0.002,
            Pose::from_translation(Vec3::new(0.0, 0.0, 0.02)),
            Vec3::new(1.0, 0.4, 0.1),
        );
        let world = b.build();
        let camera = Camera::look_at(80, 60, 80.0, Vec3::new(0.3, 0.0, 0.35), Vec3::ZERO);
        let mut image = CpuRenderer::new(RenderSettings::default())
            .forward(
                &GaussianCloud::from_world(&world),
                &camera,
                Roi::full(&camera),
            )
            .colour;
        // A white arm covers the left part of the box in the image; the model knows nothing of it.
        let columns: Vec<u32> = (0..80)
            .filter(|&x| (0..60).any(|y| image[(y * 80 + x) as usize].x > 0.5))
            .collect();
        let split = columns[columns.len() / 2];
        for y in 0..60 {
            for x in 0..split {
                image[(y * 80 + x) as usize] = Vec3::splat(0.9);
            }
        }
        let force = |threshold: f32| {
            let mut w = world.clone();
            let config = CorrectConfig {
                occluder_threshold: threshold,
                ..Default::default()
            };
            let stats = correct_once(&mut w, config, camera, &image);
            (stats.force[0].length(), stats.occluded_pixels)
        };
        let (pushed, _) = force(0.0);
        let (kept, occluded) = force(0.35);
        assert!(occluded > 100, "the arm's pixels are found: {occluded}");
        assert!(
            pushed > 1e-3 && kept < 0.2 * pushed,
            "force with the arm in the loss {pushed} N, without {kept} N"
        );
    }

    /// A camera whose pose changes every tick (hung from a tf-moved frame) renders its static
    /// scene anew each time but does not make the cache grow without bound.
    #[test]
    fn a_moving_camera_does_not_grow_the_background_cache() {
        let world = crate::world::WorldBuilder::new().build();
        let mut c = Corrector::new(CorrectConfig::default(), RenderSettings::default()).unwrap();
        for k in 0..40 {
            let eye = Vec3::new(1.0, 0.01 * k as f32, 0.6);
            let camera = Camera::look_at(16, 9, 30.0, eye, Vec3::ZERO);
            assert_eq!(c.background(&world, &camera).unwrap().len(), 16 * 9);
        }
        assert_eq!(c.backgrounds.len(), MAX_BACKGROUNDS);
    }

    #[test]
    fn a_steady_displacement_settles_the_push_at_gain_plus_integral_over_leak() {
        let c = CorrectConfig {
            integral: 2000.0,
            integral_leak: 2.0,
            ..CorrectConfig::default()
        };
        let dt = 1.0 / 30.0;
        let d = Vec3::new(0.0, 0.003, 0.0);
        let mut state = DisplacementState::default();
        // The first tick: the gain and the whole displacement as its change, one tick integrated.
        let first = state.acceleration(d, &c, dt);
        let expected = c.gain * d + c.damping * d / dt + c.integral * d * dt;
        assert!(first.distance(expected) < 1e-3, "{first} vs {expected}");
        // Held for 10 s (20 leak time constants): the integral settles where the leak takes
        // what a tick adds, at d / leak.
        let mut last = first;
        for _ in 0..300 {
            last = state.acceleration(d, &c, dt);
        }
        let settled = (c.gain + c.integral / c.integral_leak) * d;
        assert!(
            last.distance(settled) < 1e-3 * settled.length(),
            "{last} vs {settled}"
        );
        // When the displacement goes, the integral keeps pushing, leaking away.
        let after = state.acceleration(Vec3::ZERO, &c, dt);
        assert!(after.y > 0.0 && after.y < last.y - c.gain * d.y, "{after}");
        // Without the integral a steady displacement pushes by the gain alone.
        let mut plain = DisplacementState::default();
        let c0 = CorrectConfig::default();
        for _ in 0..30 {
            last = plain.acceleration(d, &c0, dt);
        }
        assert!(last.distance(c0.gain * d) < 1e-6, "{last}");
        assert_eq!(plain.acceleration(Vec3::ZERO, &c0, dt), Vec3::ZERO);
    }
}
