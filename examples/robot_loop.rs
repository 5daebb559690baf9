//! Drive a live STE session from your own robot loop, with PlumeNet's bank of the room.
//!
//! ```sh
//! cargo run --release --example robot_loop
//! ```
//!
//! A robot sends what its gas sensor read, where and when ([`Session::add_readings`]), asks
//! for an iteration ([`Session::iterate`]) and drives along the path to the goal it gets,
//! until the session is done. Here a toy robot stands in for yours: it drives at 0.25 m/s in
//! straight legs and carries a simulated uncalibrated MOX sensor (Sensor II, raw volts) in the
//! mean plume of a leak at (4.5, 2.5) m in the paper's arena. Replace `drive_and_read` with
//! your robot's motion and sensor; the session never sees the true source.

use plumenet::{
    Feature, Layout, MoxSensor, RoomBanks, Sample, SensorPreset, Session, SessionConfig, Surrogate,
    Transport, WindField,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The toy robot's speed (m/s) and its sensor's sampling period (s).
const SPEED_MPS: f64 = 0.25;
const PERIOD_S: f64 = 0.1;

/// A simulated robot: its position, clock, sensor and the mean plume it senses.
struct ToyRobot {
    position: [f64; 2],
    t: f64,
    sensor: MoxSensor,
    rng: ChaCha8Rng,
    plume: ndarray::Array2<f64>,
    room: Layout,
}

impl ToyRobot {
    /// Drives along `path` and returns one reading per sampling period.
    fn drive_and_read(&mut self, path: &[[f64; 2]]) -> Vec<Sample> {
        let mut readings = Vec::new();
        for goal in path {
            let [x0, y0] = self.position;
            let length = (goal[0] - x0).hypot(goal[1] - y0);
            let steps = (length / (SPEED_MPS * PERIOD_S)).ceil().max(1.0) as usize;
            for s in 1..=steps {
                let f = s as f64 / steps as f64;
                let (x, y) = (x0 + f * (goal[0] - x0), y0 + f * (goal[1] - y0));
                self.t += PERIOD_S;
                let (j, i) = self.room.cell_of(x, y);
                let value = self
                    .sensor
                    .sample(self.plume[[j, i]], PERIOD_S, &mut self.rng);
                readings.push(Sample {
                    t: self.t,
                    x,
                    y,
                    value,
                });
            }
            self.position = *goal;
        }
        readings
    }
}

fn main() -> plumenet::Result<()> {
    let room = Layout::load("data/layouts/wind-tunnel.json".as_ref())?;
    let model = Surrogate::load("models/default".as_ref())?;
    // Candidate sources every 0.25 m, as on the command line (a coarser grid leaves the leak
    // between candidates, and a wrong plume can fit better than the nearest one); the bank is
    // PlumeNet's, one predicted field per candidate.
    let (banks, _) = RoomBanks::build(room.clone(), &model, 0.25, None)?;
    let config = SessionConfig {
        ste: banks.ste_params(Feature::Rank),
        ..plumenet::EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII).session(0)
    };
    let mut session = Session::new(&banks, config)?;

    let leak = [4.5, 2.5];
    let mut robot = ToyRobot {
        position: [15.0, 1.0],
        t: 0.0,
        sensor: MoxSensor::preset(SensorPreset::SensorII, true)?,
        rng: ChaCha8Rng::seed_from_u64(7),
        plume: Transport::new(&room, &WindField::solve(&room)?)?.solve(leak[0], leak[1])?,
        room,
    };
    // The sensor settles where the robot stands before the search starts.
    let settle = vec![robot.position; 100];
    let readings = robot.drive_and_read(&settle);
    session.add_readings(&readings)?;

    loop {
        let step = session.iterate(Some(robot.position))?;
        println!(
            "iteration {:2}: estimate ({:5.2}, {:4.2}) m, entropy {:4.2} nats, 90% region {} cells",
            step.iteration,
            step.estimate[0],
            step.estimate[1],
            step.entropy,
            step.credible_region.len()
        );
        if step.done {
            let error = (step.estimate[0] - leak[0]).hypot(step.estimate[1] - leak[1]);
            println!(
                "{} after {} readings: {error:.2} m from the leak",
                if step.converged {
                    "converged"
                } else {
                    "stopped at the iteration limit"
                },
                step.readings
            );
            // Found: within two candidate cells of the leak.
            assert!(error < 0.75, "error {error} m");
            return Ok(());
        }
        let readings = robot.drive_and_read(&step.path);
        session.add_readings(&readings)?;
    }
}
