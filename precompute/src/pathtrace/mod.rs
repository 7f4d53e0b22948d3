//! Fiber-level path tracing: the reference every faster method in twill is measured against.
//!
//! [`camera`] makes primary rays, [`light`] holds directional and SG lights, and [`integrator`]
//! traces paths through a tiled fiber fabric: next-event estimation toward every light plus
//! BCSDF-sampled continuation, combined for SG lights by multiple importance sampling (power
//! heuristic), with Russian roulette after the third scattering event. Paths can be restricted
//! to single scattering (exactly one fiber interaction) or to multiple scattering (two or more),
//! so later approximations of each component are validated separately. Each pixel's samples
//! are independent estimates accumulated in a [`crate::image::Film`] with their variance.

pub mod camera;
pub mod integrator;
pub mod light;

pub use camera::{Camera, Projection};
pub use integrator::{Component, PathScene, RenderSettings, render};
pub use light::Light;
