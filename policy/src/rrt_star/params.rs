//! RRT*'s tunable parameters: their specs (names, bounds, defaults) and the vector form.

use super::*;

/// The tunable parameters, in vector order.
pub fn param_specs() -> Vec<ParamSpec> {
    let p = ParamSpec::new;
    let mut specs = vec![
        p(
            "replan_every",
            10.0,
            1.0,
            50.0,
            "steps between replans (rounded)",
        ),
        p("horizon_min", 5.0, 2.0, 20.0, "shortest planning window, m"),
        p(
            "horizon_time",
            1.0,
            0.1,
            3.0,
            "planning window in seconds at the current speed, if longer",
        ),
        p(
            "iterations",
            120.0,
            20.0,
            1000.0,
            "samples per replan (rounded)",
        ),
        p(
            "step_size",
            1.2,
            0.2,
            4.0,
            "longest edge along the track, m",
        ),
        p(
            "rewire_radius",
            1.8,
            0.3,
            6.0,
            "neighbours within this distance are parent candidates and rewired, m",
        ),
        p(
            "goal_bias",
            0.15,
            0.0,
            1.0,
            "probability of sampling the goal on the driving line",
        ),
        p(
            "lateral_span",
            1.5,
            0.1,
            4.0,
            "samples have offsets in [-span, span] from the driving line, m",
        ),
        p(
            "max_slope",
            0.5,
            0.05,
            1.5,
            "largest lateral slope dd/du of an edge",
        ),
        p(
            "wall_margin",
            0.15,
            0.0,
            0.5,
            "the car's box grows by this against walls, m",
        ),
        p(
            "car_margin",
            0.15,
            0.0,
            1.5,
            "the car's box grows by this against cars and obstacles, m",
        ),
        p(
            "w_offset",
            0.5,
            0.0,
            20.0,
            "cost per metre of offset per metre travelled",
        ),
        p(
            "w_opponent",
            5.0,
            0.0,
            50.0,
            "cost of proximity to the other cars' predicted boxes",
        ),
    ];
    specs.extend(tracker::param_specs(
        "multiplies the driving line's speed profile",
        "lateral acceleration allowed on the plan, m/s^2",
    ));
    specs
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RrtStarParams {
    pub replan_every: usize,
    pub horizon_min: f64,
    pub horizon_time: f64,
    pub iterations: usize,
    pub step_size: f64,
    pub rewire_radius: f64,
    pub goal_bias: f64,
    pub lateral_span: f64,
    pub max_slope: f64,
    pub wall_margin: f64,
    pub car_margin: f64,
    pub w_offset: f64,
    pub w_opponent: f64,
    /// The tracker's parameters (the vector's last [`tracker::NUM_PARAMS`]).
    #[serde(flatten)]
    pub tracker: TrackerParams,
    /// From the car (not tuned): body length and width.
    pub length: f64,
    pub width: f64,
}

impl Default for RrtStarParams {
    fn default() -> Self {
        Self::from_vector(&default_values(&param_specs()), &VehicleParams::default())
            .expect("defaults are valid")
    }
}

impl RrtStarParams {
    /// From a vector in [`param_specs`] order (bounds checked by the caller); checks the
    /// relations between parameters.
    pub fn from_vector(v: &[f64], vehicle: &VehicleParams) -> Result<Self, PolicyError> {
        let tracker = TrackerParams::after_own(NAME, v, OWN_PARAMS, vehicle)?;
        let p = Self {
            replan_every: rounded_count(v[0]),
            horizon_min: v[1],
            horizon_time: v[2],
            iterations: rounded_count(v[3]),
            step_size: v[4],
            rewire_radius: v[5],
            goal_bias: v[6],
            lateral_span: v[7],
            max_slope: v[8],
            wall_margin: v[9],
            car_margin: v[10],
            w_offset: v[11],
            w_opponent: v[12],
            tracker,
            length: vehicle.length,
            width: vehicle.width,
        };
        if p.step_size > p.horizon_min {
            return Err(PolicyError::Invalid {
                driver: NAME.into(),
                message: format!(
                    "parameter step_size = {} must not exceed horizon_min = {}",
                    p.step_size, p.horizon_min
                ),
            });
        }
        Ok(p)
    }
}
