//! The ROS 2 side of the live STE: the messages the node speaks, as serde structs whose field
//! order is their CDR wire order (the ROS IDL definitions), and the conversions between them and
//! the STE's types. Pure and always compiled, so the conversions are tested in every build; the
//! DDS transport that publishes and subscribes them is the `ros2` feature's.
//!
//! The node subscribes to the gas readings (`std_msgs/Float64` or `Float32`) and the robot's
//! pose (`geometry_msgs/PoseStamped` or `nav_msgs/Odometry`), pairs each reading with the pose
//! at its time ([`Pairer`]: linear interpolation between the poses around it), and publishes the
//! next goal (`geometry_msgs/PoseStamped`, facing along the last leg of its path, Nav2's
//! `goal_pose` convention), the belief (`nav_msgs/OccupancyGrid`, so RViz shows it), the
//! estimate (`geometry_msgs/PointStamped`) and the estimate with the posterior's spread about it
//! (`geometry_msgs/PoseWithCovarianceStamped`).

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use crate::layout::Layout;
use crate::ste::posterior::Sample;

/// The message types (ROS 2 IDL layouts).
pub mod msg {
    use serde::{Deserialize, Serialize};

    /// `builtin_interfaces/Time`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
    pub struct Time {
        /// Whole seconds.
        pub sec: i32,
        /// Nanoseconds, `0..1e9`.
        pub nanosec: u32,
    }

    impl Time {
        /// The time `seconds` after the epoch (rounded to the nanosecond; clamped to `i32`
        /// seconds).
        pub fn from_secs(seconds: f64) -> Self {
            let whole = seconds.floor();
            let mut nanosec = ((seconds - whole) * 1e9).round() as i64;
            let mut sec = whole as i64;
            if nanosec >= 1_000_000_000 {
                nanosec -= 1_000_000_000;
                sec += 1;
            }
            Self {
                sec: sec.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32,
                nanosec: nanosec as u32,
            }
        }

        /// Seconds after the epoch.
        pub fn secs(&self) -> f64 {
            f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
        }
    }

    /// `std_msgs/Header`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct Header {
        /// When.
        pub stamp: Time,
        /// In which frame.
        pub frame_id: String,
    }

    /// `std_msgs/Float64`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Float64 {
        /// The value.
        pub data: f64,
    }

    /// `std_msgs/Float32`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Float32 {
        /// The value.
        pub data: f32,
    }

    /// `geometry_msgs/Point` (also the layout of `Vector3`).
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Point {
        /// x (m).
        pub x: f64,
        /// y (m).
        pub y: f64,
        /// z (m).
        pub z: f64,
    }

    /// `geometry_msgs/Quaternion`.
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    pub struct Quaternion {
        /// x.
        pub x: f64,
        /// y.
        pub y: f64,
        /// z.
        pub z: f64,
        /// w.
        pub w: f64,
    }

    impl Default for Quaternion {
        fn default() -> Self {
            Self {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            }
        }
    }

    impl Quaternion {
        /// A rotation by `yaw` (rad) about z.
        pub fn from_yaw(yaw: f64) -> Self {
            Self {
                x: 0.0,
                y: 0.0,
                z: (0.5 * yaw).sin(),
                w: (0.5 * yaw).cos(),
            }
        }

        /// The rotation's yaw (rad, in `(-pi, pi]`).
        pub fn yaw(&self) -> f64 {
            (2.0 * (self.w * self.z + self.x * self.y))
                .atan2(1.0 - 2.0 * (self.y * self.y + self.z * self.z))
        }
    }

    /// `geometry_msgs/Pose`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Pose {
        /// Where.
        pub position: Point,
        /// Which way.
        pub orientation: Quaternion,
    }

    /// `geometry_msgs/PoseStamped`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct PoseStamped {
        /// Time and frame.
        pub header: Header,
        /// The pose.
        pub pose: Pose,
    }

    /// `geometry_msgs/PointStamped`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct PointStamped {
        /// Time and frame.
        pub header: Header,
        /// The point.
        pub point: Point,
    }

    /// A 6 x 6 covariance, row-major (a fixed array on the wire).
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct Covariance(pub [f64; 36]);

    impl Default for Covariance {
        fn default() -> Self {
            Self([0.0; 36])
        }
    }

    impl Serialize for Covariance {
        fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
            use serde::ser::SerializeTuple;
            let mut t = s.serialize_tuple(36)?;
            for v in &self.0 {
                t.serialize_element(v)?;
            }
            t.end()
        }
    }

    impl<'de> Deserialize<'de> for Covariance {
        fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            struct Visitor;
            impl<'de> serde::de::Visitor<'de> for Visitor {
                type Value = Covariance;
                fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                    f.write_str("36 numbers")
                }
                fn visit_seq<A: serde::de::SeqAccess<'de>>(
                    self,
                    mut seq: A,
                ) -> Result<Covariance, A::Error> {
                    let mut out = [0.0; 36];
                    for (k, slot) in out.iter_mut().enumerate() {
                        *slot = seq
                            .next_element()?
                            .ok_or_else(|| serde::de::Error::invalid_length(k, &self))?;
                    }
                    Ok(Covariance(out))
                }
            }
            d.deserialize_tuple(36, Visitor)
        }
    }

    /// `geometry_msgs/PoseWithCovariance`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct PoseWithCovariance {
        /// The pose.
        pub pose: Pose,
        /// Its covariance.
        pub covariance: Covariance,
    }

    /// `geometry_msgs/PoseWithCovarianceStamped`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct PoseWithCovarianceStamped {
        /// Time and frame.
        pub header: Header,
        /// The pose and its covariance.
        pub pose: PoseWithCovariance,
    }

    /// `geometry_msgs/Twist`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct Twist {
        /// Linear velocity (a `Vector3`).
        pub linear: Point,
        /// Angular velocity (a `Vector3`).
        pub angular: Point,
    }

    /// `geometry_msgs/TwistWithCovariance`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct TwistWithCovariance {
        /// The twist.
        pub twist: Twist,
        /// Its covariance.
        pub covariance: Covariance,
    }

    /// `nav_msgs/Odometry`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct Odometry {
        /// Time and frame.
        pub header: Header,
        /// The child frame.
        pub child_frame_id: String,
        /// The pose.
        pub pose: PoseWithCovariance,
        /// The twist.
        pub twist: TwistWithCovariance,
    }

    /// `nav_msgs/MapMetaData`.
    #[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
    pub struct MapMetaData {
        /// When the map was loaded.
        pub map_load_time: Time,
        /// Cell size (m).
        pub resolution: f32,
        /// Cells along x.
        pub width: u32,
        /// Cells along y.
        pub height: u32,
        /// The pose of cell (0, 0)'s corner.
        pub origin: Pose,
    }

    /// `nav_msgs/OccupancyGrid`.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    pub struct OccupancyGrid {
        /// Time and frame.
        pub header: Header,
        /// Size and placement.
        pub info: MapMetaData,
        /// Row-major values (row = y index), 0-100, or -1 for unknown.
        pub data: Vec<i8>,
    }
}

use msg::{
    Covariance, Header, MapMetaData, OccupancyGrid, Point, PointStamped, Pose, PoseStamped,
    PoseWithCovariance, PoseWithCovarianceStamped, Quaternion, Time,
};

fn header(frame_id: &str, t: f64) -> Header {
    Header {
        stamp: Time::from_secs(t),
        frame_id: frame_id.to_string(),
    }
}

/// The next goal as a `PoseStamped` facing along the last leg of `path` (yaw 0 when the path
/// has no length).
pub fn goal_pose(goal: [f64; 2], path: &[[f64; 2]], frame_id: &str, t: f64) -> PoseStamped {
    let yaw = path
        .windows(2)
        .rev()
        .find(|w| w[0] != w[1])
        .map_or(0.0, |w| (w[1][1] - w[0][1]).atan2(w[1][0] - w[0][0]));
    PoseStamped {
        header: header(frame_id, t),
        pose: Pose {
            position: Point {
                x: goal[0],
                y: goal[1],
                z: 0.0,
            },
            orientation: Quaternion::from_yaw(yaw),
        },
    }
}

/// The estimate as a `PointStamped`.
pub fn estimate_point(estimate: [f64; 2], frame_id: &str, t: f64) -> PointStamped {
    PointStamped {
        header: header(frame_id, t),
        point: Point {
            x: estimate[0],
            y: estimate[1],
            z: 0.0,
        },
    }
}

/// The estimate with the posterior's spread about it as a `PoseWithCovarianceStamped` (RViz
/// draws it as an ellipse): the x and y entries of the covariance are the posterior's second
/// moments about the estimate, `sum_j p_j (x_j - x)(y_j - y)` and the like, so that the
/// ellipse grows with the posterior's own account of how far off the estimate is. The height
/// and the orientation are unknown: their variances are [`UNKNOWN_VARIANCE`].
pub fn estimate_with_covariance(
    estimate: [f64; 2],
    candidates: &[[f64; 2]],
    posterior: &[f64],
    frame_id: &str,
    t: f64,
) -> PoseWithCovarianceStamped {
    let mut m = [[0.0; 2]; 2];
    for (c, p) in candidates.iter().zip(posterior) {
        let d = [c[0] - estimate[0], c[1] - estimate[1]];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v += p * d[i] * d[j];
            }
        }
    }
    let mut covariance = [0.0; 36];
    covariance[0] = m[0][0];
    covariance[1] = m[0][1];
    covariance[6] = m[1][0];
    covariance[7] = m[1][1];
    for k in [14, 21, 28, 35] {
        covariance[k] = UNKNOWN_VARIANCE;
    }
    PoseWithCovarianceStamped {
        header: header(frame_id, t),
        pose: PoseWithCovariance {
            pose: Pose {
                position: Point {
                    x: estimate[0],
                    y: estimate[1],
                    z: 0.0,
                },
                orientation: Quaternion::from_yaw(0.0),
            },
            covariance: Covariance(covariance),
        },
    }
}

/// The variance of a pose component the estimate says nothing about (height, orientation).
pub const UNKNOWN_VARIANCE: f64 = 1e9;

/// The belief as an `OccupancyGrid` over the arena at the candidates' spacing: each
/// candidate's cell holds its probability scaled so that the most probable is 100; cells
/// without a candidate (obstacles, the border) are unknown (-1).
pub fn belief_grid(
    layout: &Layout,
    candidates: &[[f64; 2]],
    posterior: &[f64],
    spacing_m: f64,
    frame_id: &str,
    t: f64,
) -> OccupancyGrid {
    let width = (layout.width() / spacing_m).round() as usize;
    let height = (layout.height() / spacing_m).round() as usize;
    let top = posterior.iter().copied().fold(0.0, f64::max);
    let mut data = vec![-1i8; width * height];
    for (c, p) in candidates.iter().zip(posterior) {
        let i = ((c[0] / spacing_m).floor() as usize).min(width.saturating_sub(1));
        let j = ((c[1] / spacing_m).floor() as usize).min(height.saturating_sub(1));
        data[j * width + i] = if top > 0.0 {
            (100.0 * p / top).round() as i8
        } else {
            0
        };
    }
    OccupancyGrid {
        header: header(frame_id, t),
        info: MapMetaData {
            map_load_time: Time::from_secs(t),
            resolution: spacing_m as f32,
            width: width as u32,
            height: height as u32,
            origin: Pose::default(),
        },
        data,
    }
}

/// Pairs gas readings with the robot's poses by time: a reading gets the position interpolated
/// linearly between the poses just before and after it. A reading waits until a pose at or
/// after its time has arrived; one older than every pose kept is dropped (and counted).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Pairer {
    poses: VecDeque<(f64, [f64; 2])>,
    waiting: VecDeque<(f64, f64)>,
    dropped: usize,
}

impl Pairer {
    /// A pairer with nothing yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// A pose at time `t` (poses arrive in time order; an older one is ignored).
    pub fn pose(&mut self, t: f64, xy: [f64; 2]) {
        if self.poses.back().is_none_or(|&(last, _)| t >= last) {
            self.poses.push_back((t, xy));
        }
    }

    /// A reading at time `t`.
    pub fn reading(&mut self, t: f64, value: f64) {
        self.waiting.push_back((t, value));
    }

    /// Readings dropped for lack of a pose before them.
    pub fn dropped(&self) -> usize {
        self.dropped
    }

    /// The readings that can be placed now, in time order; poses no longer needed are
    /// forgotten.
    pub fn paired(&mut self) -> Vec<Sample> {
        let mut out = Vec::new();
        while let Some(&(t, value)) = self.waiting.front() {
            let Some(&(last, _)) = self.poses.back() else {
                break;
            };
            if t > last {
                break;
            }
            self.waiting.pop_front();
            // A pose at or after `t` exists: `t` is no later than the newest.
            let k = self
                .poses
                .iter()
                .position(|&(tp, _)| tp >= t)
                .unwrap_or(self.poses.len() - 1);
            let (t1, p1) = self.poses[k];
            if k == 0 {
                if t1 > t {
                    self.dropped += 1;
                } else {
                    out.push(Sample {
                        t,
                        x: p1[0],
                        y: p1[1],
                        value,
                    });
                }
                continue;
            }
            let (t0, p0) = self.poses[k - 1];
            let w = if t1 > t0 { (t - t0) / (t1 - t0) } else { 1.0 };
            out.push(Sample {
                t,
                x: p0[0] + w * (p1[0] - p0[0]),
                y: p0[1] + w * (p1[1] - p0[1]),
                value,
            });
        }
        // Keep the last pose before the next waiting reading (or the newest pose).
        let horizon = self.waiting.front().map_or(f64::INFINITY, |&(t, _)| t);
        while self.poses.len() > 1 && self.poses[1].0 <= horizon {
            self.poses.pop_front();
        }
        out
    }
}

#[cfg(feature = "ros2")]
pub mod node;
