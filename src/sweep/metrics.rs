//! A run's summary numbers ([`Metric`]), accumulated frame by frame as the frames go to the
//! run's output.

use std::io;

use glam::DVec3;
use serde::{Deserialize, Serialize};
use serde_json::Value as Json;

use crate::output::{Frame, FrameSink, Header};

/// A summary number of a run, computed from its frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Metric {
    /// Frames written.
    Frames,
    /// Time of the last frame, s.
    FinalTime,
    /// Kinetic energy at the last frame, J.
    FinalKineticEnergy,
    /// Elastic energy at the last frame, J.
    FinalElasticEnergy,
    /// Total energy (kinetic + gravitational + elastic) at the last frame, J.
    FinalTotalEnergy,
    /// Largest kinetic energy of any frame, J.
    MaxKineticEnergy,
    /// Speed of the fastest particle at the last frame, m/s.
    FinalMaxSpeed,
    /// Speed of the fastest particle at any frame, m/s.
    MaxSpeed,
    /// Lowest y of any particle at any frame, m.
    MinHeight,
    /// Centre of mass at the last frame, `[x, y, z]` m.
    FinalCenter,
    /// Distance of the centre of mass at the last frame from the first frame's, m.
    CenterDisplacement,
    /// Largest |ℓ − r| / r of any spring at any frame.
    MaxStrain,
}

impl Metric {
    /// Every metric, in the order the manifest lists them.
    pub const ALL: [Metric; 12] = [
        Metric::Frames,
        Metric::FinalTime,
        Metric::FinalKineticEnergy,
        Metric::FinalElasticEnergy,
        Metric::FinalTotalEnergy,
        Metric::MaxKineticEnergy,
        Metric::FinalMaxSpeed,
        Metric::MaxSpeed,
        Metric::MinHeight,
        Metric::FinalCenter,
        Metric::CenterDisplacement,
        Metric::MaxStrain,
    ];

    /// The metric's name in sweep files and manifests.
    pub fn name(self) -> &'static str {
        match self {
            Metric::Frames => "frames",
            Metric::FinalTime => "final_time",
            Metric::FinalKineticEnergy => "final_kinetic_energy",
            Metric::FinalElasticEnergy => "final_elastic_energy",
            Metric::FinalTotalEnergy => "final_total_energy",
            Metric::MaxKineticEnergy => "max_kinetic_energy",
            Metric::FinalMaxSpeed => "final_max_speed",
            Metric::MaxSpeed => "max_speed",
            Metric::MinHeight => "min_height",
            Metric::FinalCenter => "final_center",
            Metric::CenterDisplacement => "center_displacement",
            Metric::MaxStrain => "max_strain",
        }
    }
}

impl std::str::FromStr for Metric {
    type Err = String;
    fn from_str(s: &str) -> Result<Metric, String> {
        Metric::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Metric::ALL.iter().map(|m| m.name()).collect();
                format!("unknown metric `{s}`; expected one of {}", names.join(", "))
            })
    }
}

/// The metrics' running values over a run's frames.
#[derive(Default)]
pub(super) struct Accumulator {
    masses: Vec<f64>,
    springs: Vec<[u32; 2]>,
    rest: Vec<f64>,
    frames: u64,
    final_time: f64,
    final_energies: Option<softbody_scene::Energies>,
    max_kinetic: f64,
    final_max_speed: f64,
    max_speed: f64,
    min_height: f64,
    first_center: Option<DVec3>,
    final_center: DVec3,
    max_strain: f64,
    /// Whether strains are wanted (they cost a pass over the springs per frame).
    strain: bool,
}

impl Accumulator {
    /// No frames yet; `strain`: whether [`Metric::MaxStrain`] is wanted.
    pub(super) fn new(strain: bool) -> Accumulator {
        Accumulator {
            strain,
            ..Accumulator::default()
        }
    }

    fn header(&mut self, h: &Header) {
        self.masses = h.masses.clone();
        if self.strain {
            self.springs = h.springs.clone();
            self.rest = h.rest.clone();
        }
        self.min_height = f64::INFINITY;
    }

    fn frame(&mut self, f: &Frame<'_>) {
        self.frames += 1;
        self.final_time = f.time;
        self.final_energies = Some(f.energies);
        self.max_kinetic = self.max_kinetic.max(f.energies.kinetic);
        let speed = f.velocities.iter().map(|v| v.length()).fold(0.0, f64::max);
        self.final_max_speed = speed;
        self.max_speed = self.max_speed.max(speed);
        let low = f
            .positions
            .iter()
            .map(|x| x.y)
            .fold(f64::INFINITY, f64::min);
        self.min_height = self.min_height.min(low);
        let mass: f64 = self.masses.iter().sum();
        let moment = f
            .positions
            .iter()
            .zip(&self.masses)
            .fold(DVec3::ZERO, |s, (x, m)| s + *x * *m);
        let center = if mass > 0.0 {
            moment / mass
        } else {
            DVec3::ZERO
        };
        self.first_center.get_or_insert(center);
        self.final_center = center;
        for ([a, b], r) in self.springs.iter().zip(&self.rest) {
            let length = (f.positions[*a as usize] - f.positions[*b as usize]).length();
            if *r > 0.0 {
                self.max_strain = self.max_strain.max(((length - r) / r).abs());
            }
        }
    }

    pub(super) fn value(&self, metric: Metric) -> Json {
        let e = self.final_energies.unwrap_or_default();
        let number = |x: f64| serde_json::Number::from_f64(x).map_or(Json::Null, Json::Number);
        if self.frames == 0 {
            return if metric == Metric::Frames {
                0.into()
            } else {
                Json::Null
            };
        }
        match metric {
            Metric::Frames => self.frames.into(),
            Metric::FinalTime => number(self.final_time),
            Metric::FinalKineticEnergy => number(e.kinetic),
            Metric::FinalElasticEnergy => number(e.elastic),
            Metric::FinalTotalEnergy => number(e.total()),
            Metric::MaxKineticEnergy => number(self.max_kinetic),
            Metric::FinalMaxSpeed => number(self.final_max_speed),
            Metric::MaxSpeed => number(self.max_speed),
            Metric::MinHeight => number(self.min_height),
            Metric::FinalCenter => Json::Array(
                self.final_center
                    .to_array()
                    .into_iter()
                    .map(number)
                    .collect(),
            ),
            Metric::CenterDisplacement => number(
                (self.final_center - self.first_center.unwrap_or(self.final_center)).length(),
            ),
            Metric::MaxStrain => number(self.max_strain),
        }
    }
}

/// The metrics watch the run as the run service's observer.
impl FrameSink for Accumulator {
    fn header(&mut self, h: &Header) -> io::Result<()> {
        Accumulator::header(self, h);
        Ok(())
    }
    fn frame(&mut self, f: &Frame<'_>) -> io::Result<()> {
        Accumulator::frame(self, f);
        Ok(())
    }
    fn finish(&mut self) -> io::Result<()> {
        Ok(())
    }
    fn wants_springs(&self) -> bool {
        self.strain
    }
}
