//! The ROS 2 node (feature `ros2`): the live session on ROS topics, through `ros2-client`
//! (RustDDS; no ROS installation needed).
//!
//! Each spin takes every waiting reading and pose, pairs them by time ([`Pairer`], on the
//! messages' DDS source timestamps, so readings and poses share one clock), and feeds the
//! placed readings to the session. The first iteration runs once a pose is known (it plans from
//! the prior); later ones whenever the robot has come within the goal tolerance of its goal.
//! Each iteration publishes the goal, the belief grid, the estimate and the estimate with its
//! covariance.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use ros2_client::{
    Context, DEFAULT_PUBLISHER_QOS, DEFAULT_SUBSCRIPTION_QOS, MessageInfo, MessageTypeName, Name,
    Node, NodeName, NodeOptions, Publisher, Subscription,
};

use super::msg::{
    Float32, Float64, OccupancyGrid, Odometry, PointStamped, PoseStamped, PoseWithCovarianceStamped,
};
use super::{Pairer, belief_grid, estimate_point, estimate_with_covariance, goal_pose};
use crate::error::{Error, Result};
use crate::ste::session::{Iteration, Session};

/// The message type of the gas readings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadingType {
    /// `std_msgs/Float64`.
    Float64,
    /// `std_msgs/Float32`.
    Float32,
}

/// The message type of the robot's pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseType {
    /// `geometry_msgs/PoseStamped`.
    PoseStamped,
    /// `nav_msgs/Odometry`.
    Odometry,
}

/// Topics, types and frame of the node.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeSettings {
    /// The node's namespace (`/` for none).
    pub namespace: String,
    /// The node's name.
    pub name: String,
    /// Gas readings in.
    pub reading_topic: String,
    /// Their type.
    pub reading_type: ReadingType,
    /// Robot pose in.
    pub pose_topic: String,
    /// Its type.
    pub pose_type: PoseType,
    /// The next goal out (`geometry_msgs/PoseStamped`).
    pub goal_topic: String,
    /// The belief out (`nav_msgs/OccupancyGrid`).
    pub belief_topic: String,
    /// The estimate out (`geometry_msgs/PointStamped`).
    pub estimate_topic: String,
    /// The estimate with the posterior's spread about it out
    /// (`geometry_msgs/PoseWithCovarianceStamped`).
    pub uncertainty_topic: String,
    /// The frame of poses, goals, grid and estimate.
    pub frame_id: String,
    /// Candidate spacing (m), the belief grid's resolution.
    pub spacing_m: f64,
    /// How close the robot must come to its goal before the next iteration (m).
    pub goal_tolerance_m: f64,
}

impl Default for NodeSettings {
    fn default() -> Self {
        Self {
            namespace: "/".into(),
            name: "plumenet".into(),
            reading_topic: "gas".into(),
            reading_type: ReadingType::Float64,
            pose_topic: "pose".into(),
            pose_type: PoseType::PoseStamped,
            goal_topic: "goal_pose".into(),
            belief_topic: "gas_source/belief".into(),
            estimate_topic: "gas_source/estimate".into(),
            uncertainty_topic: "gas_source/estimate_with_covariance".into(),
            frame_id: "map".into(),
            spacing_m: 0.25,
            goal_tolerance_m: 0.2,
        }
    }
}

fn ros_err(what: &str, e: impl std::fmt::Debug) -> Error {
    Error::Parameter(format!("ROS 2: {what}: {e:?}"))
}

/// Seconds since the epoch of a message's source timestamp (its reception time when the
/// writer sent none).
fn stamp(info: &MessageInfo) -> f64 {
    let ticks = info
        .source_timestamp()
        .unwrap_or_else(|| info.received_timestamp())
        .to_ticks();
    ticks as f64 / 4_294_967_296.0
}

enum Readings {
    F64(Subscription<Float64>),
    F32(Subscription<Float32>),
}

enum Poses {
    Stamped(Subscription<PoseStamped>),
    Odometry(Subscription<Odometry>),
}

/// The live session on ROS topics.
pub struct SteNode {
    // Keeps the DDS participant and the node's entities alive.
    _node: Node,
    readings: Readings,
    poses: Poses,
    goal: Publisher<PoseStamped>,
    belief: Publisher<OccupancyGrid>,
    estimate: Publisher<PointStamped>,
    uncertainty: Publisher<PoseWithCovarianceStamped>,
    settings: NodeSettings,
    session: Session,
    pairer: Pairer,
    position: Option<[f64; 2]>,
    target: Option<[f64; 2]>,
    done: bool,
}

impl SteNode {
    /// Joins the ROS 2 domain (of `ROS_DOMAIN_ID`, 0 by default) and makes the topics.
    ///
    /// # Errors
    /// [`Error::Parameter`] when DDS cannot start or a name is not a valid ROS name.
    pub fn new(session: Session, settings: NodeSettings) -> Result<Self> {
        let context = Context::new().map_err(|e| ros_err("cannot start DDS", e))?;
        let name = NodeName::new(&settings.namespace, &settings.name)
            .map_err(|e| ros_err("bad node name", e))?;
        let mut node = context
            .new_node(name, NodeOptions::new())
            .map_err(|e| ros_err("cannot make the node", e))?;
        let topic = |node: &Node, name: &str, package: &str, kind: &str| {
            let name = Name::parse(name).map_err(|e| ros_err("bad topic name", e))?;
            node.create_topic(
                &name,
                MessageTypeName::new(package, kind),
                &DEFAULT_SUBSCRIPTION_QOS,
            )
            .map_err(|e| ros_err("cannot make a topic", e))
        };
        let sub_err = |e| ros_err("cannot subscribe", e);
        let pub_err = |e| ros_err("cannot publish", e);
        let readings = match settings.reading_type {
            ReadingType::Float64 => {
                let t = topic(&node, &settings.reading_topic, "std_msgs", "Float64")?;
                Readings::F64(node.create_subscription(&t, None).map_err(sub_err)?)
            }
            ReadingType::Float32 => {
                let t = topic(&node, &settings.reading_topic, "std_msgs", "Float32")?;
                Readings::F32(node.create_subscription(&t, None).map_err(sub_err)?)
            }
        };
        let poses = match settings.pose_type {
            PoseType::PoseStamped => {
                let t = topic(&node, &settings.pose_topic, "geometry_msgs", "PoseStamped")?;
                Poses::Stamped(node.create_subscription(&t, None).map_err(sub_err)?)
            }
            PoseType::Odometry => {
                let t = topic(&node, &settings.pose_topic, "nav_msgs", "Odometry")?;
                Poses::Odometry(node.create_subscription(&t, None).map_err(sub_err)?)
            }
        };
        let qos = Some(DEFAULT_PUBLISHER_QOS.clone());
        let t = topic(&node, &settings.goal_topic, "geometry_msgs", "PoseStamped")?;
        let goal = node.create_publisher(&t, qos.clone()).map_err(pub_err)?;
        let t = topic(&node, &settings.belief_topic, "nav_msgs", "OccupancyGrid")?;
        let belief = node.create_publisher(&t, qos.clone()).map_err(pub_err)?;
        let t = topic(
            &node,
            &settings.estimate_topic,
            "geometry_msgs",
            "PointStamped",
        )?;
        let estimate = node.create_publisher(&t, qos.clone()).map_err(pub_err)?;
        let t = topic(
            &node,
            &settings.uncertainty_topic,
            "geometry_msgs",
            "PoseWithCovarianceStamped",
        )?;
        let uncertainty = node.create_publisher(&t, qos).map_err(pub_err)?;
        Ok(Self {
            _node: node,
            readings,
            poses,
            goal,
            belief,
            estimate,
            uncertainty,
            settings,
            session,
            pairer: Pairer::new(),
            position: None,
            target: None,
            done: false,
        })
    }

    /// The session.
    pub fn session(&self) -> &Session {
        &self.session
    }

    /// Takes every waiting message, feeds the placed readings to the session, and runs (and
    /// publishes) an iteration when one is due. Returns it.
    ///
    /// # Errors
    /// A reading the session refuses, a planner without a reachable goal, or a failed publish.
    pub fn spin_once(&mut self) -> Result<Option<Iteration>> {
        let take_err = |e| ros_err("cannot read a message", e);
        loop {
            let taken = match &self.readings {
                Readings::F64(s) => s.take().map_err(take_err)?.map(|(m, i)| (m.data, i)),
                Readings::F32(s) => s
                    .take()
                    .map_err(take_err)?
                    .map(|(m, i)| (f64::from(m.data), i)),
            };
            let Some((value, info)) = taken else { break };
            self.pairer.reading(stamp(&info), value);
        }
        loop {
            let taken = match &self.poses {
                Poses::Stamped(s) => s.take().map_err(take_err)?.map(|(m, i)| (m.pose, i)),
                Poses::Odometry(s) => s.take().map_err(take_err)?.map(|(m, i)| (m.pose.pose, i)),
            };
            let Some((pose, info)) = taken else { break };
            let xy = [pose.position.x, pose.position.y];
            self.position = Some(xy);
            self.pairer.pose(stamp(&info), xy);
        }
        let placed = self.pairer.paired();
        if !placed.is_empty() {
            self.session.add_readings(&placed)?;
        }
        let Some(position) = self.position else {
            return Ok(None);
        };
        let arrived = self.target.is_none_or(|g| {
            (g[0] - position[0]).hypot(g[1] - position[1]) <= self.settings.goal_tolerance_m
        });
        if self.done || !arrived {
            return Ok(None);
        }
        let it = self.session.iterate(Some(position))?;
        self.publish(&it)?;
        self.target = it.goal;
        self.done = it.done;
        Ok(Some(it))
    }

    fn publish(&self, it: &Iteration) -> Result<()> {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        let frame = &self.settings.frame_id;
        if let Some(goal) = it.goal {
            self.goal
                .publish(goal_pose(goal, &it.path, frame, now))
                .map_err(|e| ros_err("cannot publish the goal", e))?;
        }
        let est = self.session.estimator();
        let grid = belief_grid(
            self.session.layout(),
            est.candidates(),
            est.posterior(),
            self.settings.spacing_m,
            frame,
            now,
        );
        self.belief
            .publish(grid)
            .map_err(|e| ros_err("cannot publish the belief", e))?;
        self.estimate
            .publish(estimate_point(it.estimate, frame, now))
            .map_err(|e| ros_err("cannot publish the estimate", e))?;
        let spread =
            estimate_with_covariance(it.estimate, est.candidates(), est.posterior(), frame, now);
        self.uncertainty
            .publish(spread)
            .map_err(|e| ros_err("cannot publish the estimate's covariance", e))?;
        Ok(())
    }

    /// Spins every `period` until `stop` is set or the session is done.
    ///
    /// # Errors
    /// As [`SteNode::spin_once`].
    pub fn run(&mut self, period: Duration, stop: &AtomicBool) -> Result<()> {
        while !stop.load(Ordering::Relaxed) && !self.done {
            self.spin_once()?;
            std::thread::sleep(period);
        }
        Ok(())
    }
}
