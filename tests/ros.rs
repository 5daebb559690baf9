//! The ROS 2 messages and conversions (always built; the DDS transport is the `ros2` feature's).

use plumenet::ros::msg::{Covariance, Odometry, Quaternion, Time};
use plumenet::ros::{
    Pairer, UNKNOWN_VARIANCE, belief_grid, estimate_point, estimate_with_covariance, goal_pose,
};

use crate::common::{assert_err, wind_tunnel};

#[test]
fn times_and_headings_round_trip() {
    for t in [0.0, 0.1, 12.345_678_9, 1_700_000_000.999_999_999] {
        let stamp = Time::from_secs(t);
        assert!(stamp.nanosec < 1_000_000_000);
        assert!((stamp.secs() - t).abs() < 1e-6 * t.max(1.0), "{t}");
    }
    for yaw in [-3.0, -1.0, 0.0, 0.5, 3.1] {
        assert!((Quaternion::from_yaw(yaw).yaw() - yaw).abs() < 1e-12);
    }
    // The goal faces along the last leg of its path, whatever repeats its end.
    let g = goal_pose(
        [3.0, 2.0],
        &[[1.0, 1.0], [3.0, 1.0], [3.0, 2.0], [3.0, 2.0]],
        "map",
        5.0,
    );
    assert!((g.pose.orientation.yaw() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    assert_eq!((g.pose.position.x, g.pose.position.y), (3.0, 2.0));
    assert_eq!(g.header.frame_id, "map");
    assert_eq!(g.header.stamp, Time::from_secs(5.0));
    let p = estimate_point([4.5, 2.5], "odom", 1.0);
    assert_eq!(
        (p.point.x, p.point.y, p.header.frame_id.as_str()),
        (4.5, 2.5, "odom")
    );
}

#[test]
fn the_estimates_covariance_is_the_posteriors_spread_about_it() {
    // Half the mass at the estimate, a quarter 1 m east, a quarter 2 m north-east (2 m along x
    // and y): E[dx^2] = 0.25 + 1, E[dy^2] = 1, E[dx dy] = 1.
    let candidates = [[1.0, 1.0], [2.0, 1.0], [3.0, 3.0]];
    let posterior = [0.5, 0.25, 0.25];
    let m = estimate_with_covariance([1.0, 1.0], &candidates, &posterior, "map", 2.0);
    let c = m.pose.covariance.0;
    assert_eq!((c[0], c[1], c[6], c[7]), (1.25, 1.0, 1.0, 1.0));
    for k in [14, 21, 28, 35] {
        assert_eq!(c[k], UNKNOWN_VARIANCE);
    }
    let others = (0..36).filter(|k| ![0, 1, 6, 7, 14, 21, 28, 35].contains(k));
    assert!(others.map(|k| c[k]).all(|v| v == 0.0));
    assert_eq!((m.pose.pose.position.x, m.pose.pose.position.y), (1.0, 1.0));
    assert_eq!(m.header.frame_id, "map");
}

#[test]
fn the_belief_grid_puts_each_candidate_in_its_cell() {
    let layout = wind_tunnel();
    let candidates = layout.candidates(0.25).unwrap();
    // A posterior peaked at one candidate, brute-force placed.
    let peak = 321;
    let posterior: Vec<f64> = (0..candidates.len())
        .map(|k| {
            if k == peak {
                0.5
            } else {
                0.5 / (candidates.len() - 1) as f64
            }
        })
        .collect();
    let grid = belief_grid(&layout, &candidates, &posterior, 0.25, "map", 2.0);
    assert_eq!((grid.info.width, grid.info.height), (72, 16));
    assert_eq!(grid.data.len(), 72 * 16);
    assert_eq!(grid.info.resolution, 0.25);
    let [x, y] = candidates[peak];
    let cell = (y / 0.25).floor() as usize * 72 + (x / 0.25).floor() as usize;
    assert_eq!(grid.data[cell], 100);
    assert_eq!(grid.data.iter().filter(|&&v| v == 100).count(), 1);
    assert!(grid.data.iter().all(|&v| v == -1 || (0..=100).contains(&v)));
    // Cells without a candidate (obstacles) are unknown.
    let known = grid.data.iter().filter(|&&v| v >= 0).count();
    assert_eq!(known, candidates.len());
    let obstacle = (1.2f64 / 0.25).floor() as usize * 72 + (7.0f64 / 0.25).floor() as usize;
    assert_eq!(grid.data[obstacle], -1);
}

#[test]
fn readings_pair_with_the_pose_at_their_time() {
    let mut pairer = Pairer::new();
    pairer.reading(0.5, 9.0); // before any pose: dropped once poses arrive
    pairer.pose(1.0, [0.0, 0.0]);
    pairer.pose(3.0, [2.0, 4.0]);
    pairer.reading(1.5, 1.0);
    pairer.reading(3.0, 2.0);
    pairer.reading(3.5, 3.0); // waits for a later pose
    let out = pairer.paired();
    assert_eq!(pairer.dropped(), 1);
    assert_eq!(out.len(), 2);
    assert_eq!(
        (out[0].t, out[0].x, out[0].y, out[0].value),
        (1.5, 0.5, 1.0, 1.0)
    );
    assert_eq!((out[1].x, out[1].y), (2.0, 4.0));
    pairer.pose(2.0, [9.0, 9.0]); // out of order: ignored
    pairer.pose(4.0, [3.0, 4.0]);
    let out = pairer.paired();
    assert_eq!(out.len(), 1);
    assert_eq!((out[0].t, out[0].x, out[0].y), (3.5, 2.5, 4.0));
    assert!(pairer.paired().is_empty());
}

#[test]
fn odometry_covariances_are_fixed_arrays_of_36() {
    let mut odom = Odometry::default();
    odom.pose.covariance = Covariance(std::array::from_fn(|k| k as f64));
    let text = serde_json::to_string(&odom).unwrap();
    let back: Odometry = serde_json::from_str(&text).unwrap();
    assert_eq!(back, odom);
    let short = text.replace(",35.0]", "]");
    assert_err(
        serde_json::from_str::<Odometry>(&short),
        "invalid length 35, expected 36 numbers",
    );
}

/// Over DDS on this machine: a second node publishes readings and poses, the STE node answers
/// with a goal inside the arena and a belief grid (within 30 s; DDS discovery needs multicast on
/// loopback). Built only with `--features ros2`.
#[cfg(feature = "ros2")]
#[test]
fn the_node_answers_over_dds_loopback() {
    use plumenet::ros::msg::{Float64, OccupancyGrid, Pose, PoseStamped};
    use plumenet::ros::node::{NodeSettings, SteNode};
    use plumenet::sim::EpisodeConfig;
    use plumenet::ste::session::Session;
    use plumenet::ste::{Feature, SensorPreset};
    use ros2_client::{
        Context, DEFAULT_PUBLISHER_QOS, DEFAULT_SUBSCRIPTION_QOS, MessageTypeName, Name, NodeName,
        NodeOptions,
    };
    let c = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    let session = Session::new(&crate::ste::world().room, c.session(1)).unwrap();
    let settings = NodeSettings {
        reading_topic: "plumenet_test/gas".into(),
        pose_topic: "plumenet_test/pose".into(),
        goal_topic: "plumenet_test/goal_pose".into(),
        belief_topic: "plumenet_test/belief".into(),
        estimate_topic: "plumenet_test/estimate".into(),
        uncertainty_topic: "plumenet_test/estimate_with_covariance".into(),
        ..NodeSettings::default()
    };
    let mut ste = SteNode::new(session, settings).unwrap();
    let context = Context::new().unwrap();
    let mut robot = context
        .new_node(NodeName::new("/", "robot").unwrap(), NodeOptions::new())
        .unwrap();
    let topic = |name: &str, package: &str, kind: &str| {
        robot
            .create_topic(
                &Name::parse(name).unwrap(),
                MessageTypeName::new(package, kind),
                &DEFAULT_SUBSCRIPTION_QOS,
            )
            .unwrap()
    };
    let (gas_t, pose_t, goal_t, belief_t) = (
        topic("plumenet_test/gas", "std_msgs", "Float64"),
        topic("plumenet_test/pose", "geometry_msgs", "PoseStamped"),
        topic("plumenet_test/goal_pose", "geometry_msgs", "PoseStamped"),
        topic("plumenet_test/belief", "nav_msgs", "OccupancyGrid"),
    );
    let qos = Some(DEFAULT_PUBLISHER_QOS.clone());
    let gas = robot
        .create_publisher::<Float64>(&gas_t, qos.clone())
        .unwrap();
    let pose = robot.create_publisher::<PoseStamped>(&pose_t, qos).unwrap();
    let goals = robot
        .create_subscription::<PoseStamped>(&goal_t, None)
        .unwrap();
    let beliefs = robot
        .create_subscription::<OccupancyGrid>(&belief_t, None)
        .unwrap();
    let clock = std::time::Instant::now();
    let (mut goal, mut grid) = (None, None);
    let mut k = 0;
    while (goal.is_none() || grid.is_none()) && clock.elapsed().as_secs() < 30 {
        k += 1;
        let mut at = Pose::default();
        at.position.x = 15.0 - 0.01 * f64::from(k);
        at.position.y = 1.0;
        pose.publish(PoseStamped {
            pose: at,
            ..PoseStamped::default()
        })
        .unwrap();
        gas.publish(Float64 { data: 1.0 }).unwrap();
        ste.spin_once().unwrap();
        if let Ok(Some((g, _))) = goals.take() {
            goal = Some(g);
        }
        if let Ok(Some((b, _))) = beliefs.take() {
            grid = Some(b);
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let goal = goal.expect("a goal within 30 s");
    let (x, y) = (goal.pose.position.x, goal.pose.position.y);
    assert!(
        (0.0..=18.0).contains(&x) && (0.0..=4.0).contains(&y),
        "goal ({x}, {y})"
    );
    let grid = grid.expect("a belief grid within 30 s");
    assert_eq!((grid.info.width, grid.info.height), (72, 16));
}
