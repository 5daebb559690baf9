//! Physics of the arena: the wind field, the mean concentration of a point source, the
//! intermittent filament plume the robot senses, and the analytic reference solution.

pub mod analytic;
pub mod filament;
pub mod scheme;
pub mod sparse;
pub mod transport;
pub mod wind;
