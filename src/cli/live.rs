//! A live session for a robot: `serve`, `robot-sim` and `ros2-node`.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use plumenet::io;
use plumenet::io::sha256_hex;
use plumenet::layout::Layout;
use plumenet::physics::wind::WindField;
use plumenet::plume::{PhysicsSolver, PlumeModel};
use plumenet::sim::Reality;
use plumenet::ste::{Feature, RoomBanks, SensorPreset, SteParams};

use super::args::*;

/// What a live session needs: the layout, the plume model, the STE settings and the seed.
#[derive(Debug, Args)]
pub struct SessionArgs {
    /// Layout JSON file.
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    layout: PathBuf,
    /// Gas feature.
    #[arg(long, value_enum, default_value_t = FeatureArg::Rank)]
    feature: FeatureArg,
    #[command(flatten)]
    plume: PlumeArgs,
    #[command(flatten)]
    features: FeatureArgs,
    #[command(flatten)]
    run: RunArgs,
    /// Run seed, as `localize --seed`: the planner draws from its stream 3.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Keep only the most recent N readings in the posterior (a sliding window: memory stays
    /// flat in long sessions); default: all of them.
    #[arg(long)]
    max_readings: Option<usize>,
}

impl SessionArgs {
    /// The layout's banks, the session's settings (checked before the banks are computed)
    /// and the model; notes go to standard error (standard output may be a protocol's).
    pub(super) fn room(
        &self,
    ) -> Result<(
        RoomBanks,
        plumenet::ste::session::SessionConfig,
        Box<dyn PlumeModel>,
    )> {
        let layout = Layout::load(&self.layout)?;
        let (room, params, model) =
            self.plume
                .room(layout, &self.features, self.feature.into(), true)?;
        let mut config = self
            .run
            .config(params, SensorPreset::SensorII, model.rank_factor())
            .session(self.seed);
        config.max_readings = self.max_readings;
        Ok((room, config, model))
    }

    /// A fresh session, with the layout's and the model's names, and the session's name in a
    /// state file: the layout (its name and content), the plume model (its name and digest)
    /// and the feature, so that a state file of another session is refused.
    fn session(&self) -> Result<(plumenet::ste::session::Session, String, String, String)> {
        let (room, config, model) = self.room()?;
        let name = layout_name(&self.layout);
        let owner = format!(
            "layout {name} {}, model {} {}, feature {}",
            &sha256_hex(room.layout.to_json().as_bytes())[..16],
            model.name(),
            model.digest().chars().take(16).collect::<String>(),
            config.ste.feature.name()
        );
        let session = plumenet::ste::session::Session::new(&room, config)?;
        Ok((session, name, model.name(), owner))
    }
}

#[derive(Debug, Args)]
pub struct ServeArgs {
    #[command(flatten)]
    session: SessionArgs,
    /// Listen on this TCP address (port 0 picks a free one, printed on start); without it the
    /// session is served on standard input and output.
    #[arg(long)]
    listen: Option<String>,
    /// Keep the session's readings in this file (appended and synced before each reply) and
    /// start from what it holds.
    #[arg(long)]
    state: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct RobotSimArgs {
    /// The server, HOST:PORT (`plumenet serve --listen`).
    #[arg(long)]
    connect: String,
    /// The layout (the server's), the source and the start.
    #[command(flatten)]
    trial: TrialArgs,
    /// Sensor.
    #[arg(long, value_enum, default_value_t = SensorArg::SensorII)]
    sensor: SensorArg,
    #[command(flatten)]
    run: RunArgs,
    #[command(flatten)]
    reality: RealityArgs,
    /// Seed of the plume, the sensor noise and the default start (as `localize --seed`).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Write the outcome as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn robot_sim(a: RobotSimArgs) -> Result<()> {
    use plumenet::service::RemoteSession;
    let (layout, source) = a.trial.layout_and_source()?;
    let mismatch = a.reality.mismatch()?;
    let config = a.run.config(
        SteParams::for_feature(Feature::Rank).validate()?,
        a.sensor.into(),
        PhysicsSolver.rank_factor(),
    );
    let start = a.trial.start(&layout, &config.robot, a.seed)?;
    let wind = WindField::solve(&layout)?;
    let reality = Reality::new(&layout, &wind, mismatch)?;
    let mut server = RemoteSession::connect(a.connect.as_str())?;
    let run = plumenet::sim::episode::simulate_robot(
        &reality,
        &config.flight(),
        [source, start],
        a.seed,
        config.termination.budget(layout.free_area_m2()),
        &mut server,
    )?;
    println!(
        "estimate ({:.2}, {:.2}), error {:.2} m, {} legs, {}, {} readings",
        run.last.estimate[0],
        run.last.estimate[1],
        run.error_m,
        run.legs,
        outcome(
            run.last.converged,
            run.last.plume_signal,
            Some(run.last.plume_reached),
        ),
        run.readings
    );
    if let Some(path) = &a.json {
        io::write_json(path, &run)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

pub fn serve(a: ServeArgs) -> Result<()> {
    use plumenet::service::{StateFile, serve_lines, serve_tcp};
    use plumenet::ste::protocol::{Journal, NoJournal, Protocol};
    let (mut session, name, model, owner) = a.session.session()?;
    let mut journal: Box<dyn Journal> = match &a.state {
        None => Box::new(NoJournal),
        Some(path) => {
            let (file, restored) = StateFile::open(path, &owner)?;
            session.add_readings(&restored.readings)?;
            session.update()?;
            eprintln!(
                "state {}: {} readings in {} batches restored{}",
                path.display(),
                restored.readings.len(),
                restored.batches,
                if restored.dropped_torn_line {
                    " (a torn last line dropped)"
                } else {
                    ""
                }
            );
            Box::new(file)
        }
    };
    let mut protocol = Protocol::new(session, &name, &model);
    match &a.listen {
        None => {
            let stdin = std::io::stdin();
            serve_lines(
                &mut protocol,
                journal.as_mut(),
                stdin.lock(),
                std::io::stdout().lock(),
            )?;
        }
        Some(address) => serve_tcp(&mut protocol, journal.as_mut(), address.as_str(), |at| {
            println!("listening on {at}");
            use std::io::Write as _;
            let _ = std::io::stdout().flush();
        })?,
    }
    Ok(())
}

/// The ROS 2 node's topics, types and frame.
#[cfg(feature = "ros2")]
#[derive(Debug, Args)]
pub struct Ros2NodeArgs {
    #[command(flatten)]
    session: SessionArgs,
    /// Gas readings topic.
    #[arg(long, default_value = "gas")]
    reading_topic: String,
    /// Their type: float64 (std_msgs/Float64) or float32.
    #[arg(long, value_enum, default_value_t = ReadingTypeArg::Float64)]
    reading_type: ReadingTypeArg,
    /// Robot pose topic.
    #[arg(long, default_value = "pose")]
    pose_topic: String,
    /// Its type: pose-stamped (geometry_msgs/PoseStamped) or odometry (nav_msgs/Odometry).
    #[arg(long, value_enum, default_value_t = PoseTypeArg::PoseStamped)]
    pose_type: PoseTypeArg,
    /// Where the next goal goes (geometry_msgs/PoseStamped).
    #[arg(long, default_value = "goal_pose")]
    goal_topic: String,
    /// Where the belief goes (nav_msgs/OccupancyGrid).
    #[arg(long, default_value = "gas_source/belief")]
    belief_topic: String,
    /// Where the estimate goes (geometry_msgs/PointStamped).
    #[arg(long, default_value = "gas_source/estimate")]
    estimate_topic: String,
    /// Where the estimate with the posterior's spread about it goes
    /// (geometry_msgs/PoseWithCovarianceStamped).
    #[arg(long, default_value = "gas_source/estimate_with_covariance")]
    uncertainty_topic: String,
    /// Frame of poses, goals, grid and estimate.
    #[arg(long, default_value = "map")]
    frame_id: String,
    /// The node's namespace.
    #[arg(long, default_value = "/")]
    namespace: String,
    /// The node's name.
    #[arg(long, default_value = "plumenet")]
    name: String,
    /// How close the robot must come to its goal before the next iteration (m).
    #[arg(long, default_value_t = 0.2)]
    goal_tolerance: f64,
}

/// The gas reading message type on the command line.
#[cfg(feature = "ros2")]
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum ReadingTypeArg {
    Float64,
    Float32,
}

/// The pose message type on the command line.
#[cfg(feature = "ros2")]
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum PoseTypeArg {
    PoseStamped,
    Odometry,
}

#[cfg(feature = "ros2")]
pub fn ros2_node(a: Ros2NodeArgs) -> Result<()> {
    use plumenet::ros::node::{NodeSettings, PoseType, ReadingType, SteNode};
    let (session, name, model, _) = a.session.session()?;
    let settings = NodeSettings {
        namespace: a.namespace,
        name: a.name,
        reading_topic: a.reading_topic,
        reading_type: match a.reading_type {
            ReadingTypeArg::Float64 => ReadingType::Float64,
            ReadingTypeArg::Float32 => ReadingType::Float32,
        },
        pose_topic: a.pose_topic,
        pose_type: match a.pose_type {
            PoseTypeArg::PoseStamped => PoseType::PoseStamped,
            PoseTypeArg::Odometry => PoseType::Odometry,
        },
        goal_topic: a.goal_topic,
        belief_topic: a.belief_topic,
        estimate_topic: a.estimate_topic,
        uncertainty_topic: a.uncertainty_topic,
        frame_id: a.frame_id,
        spacing_m: a.session.plume.spacing(),
        goal_tolerance_m: a.goal_tolerance,
    };
    let mut node = SteNode::new(session, settings)?;
    eprintln!("ROS 2 node up: {name}, model {model}");
    let stop = std::sync::atomic::AtomicBool::new(false);
    node.run(std::time::Duration::from_millis(20), &stop)?;
    let it = node.session().estimator();
    println!(
        "done: estimate ({:.2}, {:.2})",
        it.estimate()[0],
        it.estimate()[1]
    );
    Ok(())
}
