//! Predict / correct on synthetic scenarios with ground truth (true world simulated and rendered by
//! pegs into three 320x180 cameras with noise and exposure drift): visual forces must pull an object
//! onto its true pose and track pushed and colliding objects far better than physics alone.

use glam::{Quat, Vec3};
use pegs::config::Config;
use pegs::inputs::TickInputs;
use pegs::math::Pose;
use pegs::scenario;
use pegs::tracker::{Change, Tracker};

/// Track `name` for `ticks` with the model started `offset` away; per-tick errors (m), averaged
/// over the scenario's objects.
fn track(name: &str, offset: Pose, ticks: u64, visual_forces: bool) -> Vec<f32> {
    track_with(name, offset, ticks, visual_forces, Config::default())
}

/// The model's configuration without gravity, ground and collisions (the visual-forces-only
/// ablation).
fn without_physics() -> Config {
    let mut config = Config::default();
    config.physics.gravity = Vec3::ZERO;
    config.physics.ground.enabled = false;
    config.physics.collisions.enabled = false;
    config
}

/// Scenario `name`'s true world (simulated by its own configuration) and the model's, started
/// `offset` away and run with `config`, with or without visual forces.
fn truth_and_model(
    name: &str,
    offset: Pose,
    config: &Config,
    visual_forces: bool,
) -> (Tracker, Tracker) {
    let truth = Tracker::new(
        scenario::build(name, Pose::IDENTITY).unwrap(),
        &scenario::truth_config(name),
        false,
    )
    .unwrap();
    let model = Tracker::new(
        scenario::build(name, offset).unwrap(),
        config,
        visual_forces,
    )
    .unwrap();
    (truth, model)
}

fn track_with(
    name: &str,
    offset: Pose,
    ticks: u64,
    visual_forces: bool,
    config: Config,
) -> Vec<f32> {
    let objects = scenario::object_names(name);
    let cameras = scenario::cameras(name, 320, 180);
    let (mut truth, mut model) = truth_and_model(name, offset, &config, visual_forces);
    let mut errors = Vec::new();
    for tick in 0..ticks {
        truth.predict().unwrap();
        let images = scenario::observe(
            truth.world(),
            &cameras,
            0.01,
            1.0 + 0.02 * (tick as f32 * 0.1).sin(),
            tick,
        );
        model
            .tick(&TickInputs::with_images(truth.time(), &cameras, images))
            .unwrap();
        let e: f32 = objects
            .iter()
            .map(|o| scenario::tracking_error(truth.world(), model.world(), o).unwrap())
            .sum();
        errors.push(e / objects.len() as f32);
    }
    errors
}

/// The start error of the scenario tests: 1 cm and 5 degrees.
fn small_offset() -> Pose {
    Pose::new(
        Vec3::new(0.01, 0.0, 0.0),
        Quat::from_rotation_z(5f32.to_radians()),
    )
}

fn mean(v: &[f32]) -> f32 {
    v.iter().sum::<f32>() / v.len() as f32
}

/// Track `name` from a 1 cm / 5 deg start error with and without visual forces for 4.5 s;
/// returns the mean error with, the mean error without, and the final error with (m).
fn with_and_without(name: &str) -> (f32, f32, f32) {
    let offset = small_offset();
    let with = track(name, offset, 135, true);
    let without = track(name, offset, 135, false);
    let (m_with, m_without) = (mean(&with), mean(&without));
    eprintln!(
        "{name}: mean error {:.2} mm with visual forces, {:.2} mm physics only (final {:.2} / {:.2} mm)",
        m_with * 1e3,
        m_without * 1e3,
        with[134] * 1e3,
        without[134] * 1e3
    );
    (m_with, m_without, with[134])
}

#[test]
fn an_object_started_3cm_and_20_degrees_off_is_pulled_onto_its_true_pose_within_2s() {
    let offset = Pose::new(
        Vec3::new(0.03, 0.0, 0.0),
        Quat::from_rotation_z(20f32.to_radians()),
    );
    let with = track("resting_box", offset, 60, true);
    let without = track("resting_box", offset, 60, false);
    eprintln!(
        "resting box from 3 cm / 20 deg: error after the first tick {:.1} mm physics only, {:.1} mm with visual forces; at 2 s {:.2} mm with, {:.1} mm physics only",
        without[0] * 1e3,
        with[0] * 1e3,
        with[59] * 1e3,
        without[59] * 1e3
    );
    // The start error as the first tick leaves it without visual forces (with them, the nudge
    // has already taken part of it: 22.2 mm).
    let start = without[0];
    assert!(start > 0.025, "the start offset must be real");
    // Pulled on: under 6 mm and a fifth of the start error (measured 2.3 mm with the pull alone,
    // 0.97 mm with the nudge; without the derivative term it stalls near 4.7 mm against static
    // friction, see src/correct/mod.rs).
    assert!(
        with[59] < 0.006 && with[59] < 0.2 * start,
        "not pulled on within 2 s: {} m",
        with[59]
    );
    assert!(
        without[59] > 0.025,
        "physics alone cannot know the true pose"
    );
}

#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_pushed_box_is_tracked_within_5mm_and_far_better_than_physics_only() {
    // The robot pushes the box 15 cm.
    let (with, without, last) = with_and_without("pushed_box");
    assert!(with < 0.005, "mean tracking error {with} m");
    assert!(
        without > 3.0 * with,
        "visual forces must clearly beat physics only ({without} vs {with})"
    );
    assert!(last < 0.005, "final error {last} m");
}

#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_pushed_t_block_is_tracked_within_5mm_mean() {
    let (with, without, last) = with_and_without("pushed_tblock");
    assert!(with < 0.005, "mean tracking error {with} m");
    assert!(
        without > 2.0 * with,
        "visual forces must clearly beat physics only ({without} vs {with})"
    );
    assert!(last < 0.003, "final error {last} m");
}

#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn two_colliding_boxes_are_both_tracked_within_5mm_mean() {
    // The rod pushes one box into the other; both start off their true poses.
    let (with, without, _) = with_and_without("two_boxes");
    assert!(with < 0.005, "mean tracking error {with} m");
    assert!(
        without > 2.0 * with,
        "visual forces must clearly beat physics only ({without} vs {with})"
    );
}

#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_t_block_pushed_over_is_tracked_through_its_fall_and_gravity_helps() {
    let offset = small_offset();
    let with = track("tblock_pushed_over", offset, 135, true);
    let visual_only = track_with("tblock_pushed_over", offset, 135, true, without_physics());
    // The fall: the rod tips the T from about 1.0 s; it lies flat by about 2.1 s.
    let fall = |e: &[f32]| mean(&e[30..70]);
    eprintln!(
        "tblock_pushed_over: mean {:.2} mm (during the fall {:.2}), visual forces only {:.2} mm (during the fall {:.2}); final {:.2} mm",
        mean(&with) * 1e3,
        fall(&with) * 1e3,
        mean(&visual_only) * 1e3,
        fall(&visual_only) * 1e3,
        with[134] * 1e3
    );
    assert!(mean(&with) < 0.005, "mean tracking error {} m", mean(&with));
    assert!(
        fall(&visual_only) > 2.0 * fall(&with),
        "the gravity prior must help during the fall"
    );
}

#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_rope_dragged_by_the_robot_stays_tracked() {
    let offset = small_offset();
    let with = track("dragged_rope", offset, 135, true);
    let without = track("dragged_rope", offset, 135, false);
    eprintln!(
        "dragged_rope: mean {:.2} mm with visual forces, {:.2} mm physics only; max {:.2} mm; final {:.2} / {:.2} mm",
        mean(&with) * 1e3,
        mean(&without) * 1e3,
        with.iter().copied().fold(0.0f32, f32::max) * 1e3,
        with[134] * 1e3,
        without[134] * 1e3
    );
    // A 1 cm thin chain: visual forces keep it within about a rope's width of the truth (measured
    // mean 8.5 mm). The rope is tied to the rod, so the physics alone follows the drag as well
    // (8.6 mm): the corrections must not cost the rope that prior. Without sharing each particle's
    // force along the chain (`correct::spread_along_ropes`) the rope kinks and is lost (141 mm at
    // 3 s), far beyond both bounds.
    assert!(mean(&with) < 0.015, "mean tracking error {} m", mean(&with));
    assert!(
        mean(&with) <= 1.1 * mean(&without) + 0.0005,
        "visual forces made the rope worse than physics alone: {} vs {} m",
        mean(&with),
        mean(&without)
    );
    assert!(with.iter().all(|&e| e < 0.03), "the rope was lost");
}

#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_box_hidden_behind_the_arm_is_recovered_after_it_reappears() {
    let name = "hidden_box";
    // The scenario really hides the box: under 10 % of it is visible in any camera from 1.0 s
    // to 2.3 s, and all of it is visible in some camera after 2.7 s.
    let cameras = scenario::cameras(name, 320, 180);
    let mut truth = Tracker::new(
        scenario::build(name, Pose::IDENTITY).unwrap(),
        &scenario::truth_config(name),
        false,
    )
    .unwrap();
    for tick in 1..=100 {
        truth.predict().unwrap();
        if tick % 10 == 0 {
            let seen = scenario::visible_fraction(truth.world(), &cameras, "box");
            let most = seen.iter().copied().fold(0.0f32, f32::max);
            if (30..=69).contains(&tick) {
                assert!(
                    most < 0.1,
                    "box visible at {:.2} s: {seen:?}",
                    tick as f32 / 30.0
                );
            } else if tick >= 80 {
                assert!(
                    most > 0.9,
                    "box still hidden at {:.2} s: {seen:?}",
                    tick as f32 / 30.0
                );
            }
        }
    }
    let offset = small_offset();
    let with = track(name, offset, 135, true);
    let without = track(name, offset, 135, false);
    let (before, hidden_end, after) = (with[29], with[71], mean(&with[105..]));
    eprintln!(
        "hidden_box: error {:.2} mm at 1.0 s, {:.2} mm when it reappears (2.4 s), {:.2} mm mean over 3.5-4.5 s (physics only {:.2} mm)",
        before * 1e3,
        hidden_end * 1e3,
        after * 1e3,
        mean(&without[105..]) * 1e3
    );
    // Behind the arm the model cannot see the hidden pull and falls behind; once the box is back
    // in view, visual forces pull the model onto it again, back to the lag it had before the arm
    // came (measured: 7.9 mm at 1 s, 15.7 mm at 2.4 s, 5.1 mm over the last second; before the
    // pose pull, which holds it closer while two cameras still see it: 6.7, 32 and 6.0 mm).
    assert!(
        hidden_end > 0.015,
        "the occlusion must cost something: {hidden_end} m"
    );
    assert!(
        after < 0.01 && after < 0.5 * hidden_end && after < before + 0.001,
        "not recovered: {after} m"
    );
    assert!(
        mean(&without[105..]) > 3.0 * after,
        "physics alone cannot follow the hidden pull"
    );
}

/// Track `name` from `offset` for `ticks`: the tracker's events, the box's agreement per tick and
/// its distance from the truth at the end (m).
fn health_of(
    name: &str,
    offset: Pose,
    ticks: u64,
) -> (Vec<pegs::tracker::TrackEvent>, Vec<f32>, f32) {
    let cameras = scenario::cameras(name, 320, 180);
    let (mut truth, mut model) = truth_and_model(name, offset, &Config::default(), true);
    let shape = model.world().shape_id("box").unwrap();
    let (mut events, mut agreement) = (Vec::new(), Vec::new());
    for tick in 0..ticks {
        truth.predict().unwrap();
        let images = scenario::observe(truth.world(), &cameras, 0.01, 1.0, tick);
        let report = model
            .tick(&TickInputs::with_images(truth.time(), &cameras, images))
            .unwrap();
        events.extend(report.track_events);
        agreement.extend(
            model
                .health()
                .agreement(shape)
                .filter(|_| report.correction.is_some()),
        );
    }
    let error = model
        .world()
        .shape_centroid(shape)
        .distance(truth.world().shape_centroid(shape));
    (events, agreement, error)
}

/// The resting box's agreement after one tick (camera 0 measures the first), its model started
/// `offset` away, with the depth an ideal camera measures or colour alone.
fn first_agreement(offset: Pose, with_depth: bool) -> f32 {
    let name = "resting_box";
    let cameras = scenario::cameras(name, 320, 180);
    let (mut truth, mut model) = truth_and_model(name, offset, &Config::default(), true);
    truth.predict().unwrap();
    let images = scenario::observe(truth.world(), &cameras, 0.01, 1.0, 0);
    let mut inputs = TickInputs::with_images(truth.time(), &cameras, images);
    if with_depth {
        let seen = scenario::observe_depth_and_labels(truth.world(), &cameras, &["box"]);
        for (image, (depth, _)) in inputs.images.iter_mut().zip(seen) {
            image.depth = Some(std::sync::Arc::new(depth));
        }
    }
    model.tick(&inputs).unwrap();
    let shape = model.world().shape_id("box").unwrap();
    model
        .health()
        .agreement(shape)
        .expect("camera 0 sees the box")
}

/// The agreement that tells a lost track reads depth as well as colour. The resting box's model
/// started 4 cm nearer camera 0 along that camera's line of sight covers the box's own pixels
/// there, so by colour it agrees about as well as the true pose does; the depth of those pixels is
/// 4 cm behind it, and by depth it agrees with almost nothing. At the true pose depth changes
/// nothing.
#[test]
fn a_model_held_off_along_a_camera_s_line_of_sight_agrees_in_colour_and_not_in_depth() {
    let world = scenario::build("resting_box", Pose::IDENTITY)
        .unwrap()
        .world;
    let centre = world.shape_centroid(world.shape_id("box").unwrap());
    let eye = scenario::cameras("resting_box", 320, 180)[0]
        .world_to_camera
        .inverse()
        .translation;
    let nearer = Pose::from_translation(0.04 * (eye - centre).normalize());
    let here = (
        first_agreement(Pose::IDENTITY, false),
        first_agreement(Pose::IDENTITY, true),
    );
    let off = (
        first_agreement(nearer, false),
        first_agreement(nearer, true),
    );
    eprintln!("agreement (colour, with depth): at the truth {here:?}, 4 cm nearer {off:?}");
    assert!(here.0 > 0.9 && here.1 > 0.9, "{here:?}");
    assert!(off.0 > 0.8, "colour alone sees the box: {off:?}");
    assert!(off.1 < 0.3, "depth sees past it: {off:?}");
}

/// Lost-track detection and re-acquisition. Started 1 cm / 5 deg off, the pushed box is tracked:
/// its silhouette agreement stays high and nothing is reported. Started 15 cm off, the model's box
/// no longer overlaps the real one (no photometric gradient reaches it): it is found in the images
/// within a third of a second, moved there with an event that says so, and tracked from there.
/// Started 40 cm off, beyond where the search looks (and off the table), it is reported lost
/// within half a second and not found again.
#[test]
fn a_model_that_no_longer_overlaps_its_object_relocates_it_or_reports_it_lost() {
    let (events, agreement, _) = health_of("pushed_box", small_offset(), 90);
    let low = agreement.iter().copied().fold(1.0f32, f32::min);
    eprintln!(
        "tracked: agreement mean {:.2}, lowest {low:.2}; events {events:?}",
        mean(&agreement)
    );
    assert!(events.is_empty(), "{events:?}");
    assert!(mean(&agreement) > 0.8, "{agreement:?}");
    let far = Pose::new(Vec3::new(0.0, 0.15, 0.0), Quat::IDENTITY);
    let (events, _, error) = health_of("pushed_box", far, 45);
    eprintln!("15 cm off: {error} m at the end; events {events:?}");
    let jump = match events.first().map(|e| (e.time, e.change)) {
        Some((t, Change::Relocated { jump_m, .. })) if t < 1.0 / 3.0 => jump_m,
        _ => panic!("not relocated within a third of a second: {events:?}"),
    };
    assert!((jump - 0.15).abs() < 0.02, "jumped {jump} m");
    assert!(error < 0.005, "{error} m from the truth after relocation");
    assert!(!events.iter().any(|e| e.lost()), "{events:?}");
    let beyond = Pose::new(Vec3::new(0.0, 0.4, 0.0), Quat::IDENTITY);
    let (events, _, _) = health_of("pushed_box", beyond, 30);
    eprintln!("40 cm off: events {events:?}");
    // 40 cm off is beyond the scene's 0.6 m table too: said once, at the start.
    let (off, rest): (Vec<_>, Vec<_>) =
        (events.iter()).partition(|e| matches!(e.change, Change::OffTable { .. }));
    assert!(off.len() == 1 && off[0].time < 0.1, "{events:?}");
    assert!(
        !rest.is_empty() && rest[0].lost() && rest[0].time < 0.5,
        "{events:?}"
    );
    assert_eq!(rest.len(), 1, "lost once, not found again: {events:?}");
}
