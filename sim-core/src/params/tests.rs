use super::*;

#[test]
fn defaults_are_the_reference_env_defaults_and_valid() {
    let p = VehicleParams::default();
    assert_eq!(p.mu, 1.0489);
    assert_eq!(p.c_sr, 5.4562);
    assert_eq!(p.inertia, 0.04712);
    assert_eq!(p.model, VehicleModel::St);
    assert_eq!(p.integrator, Integrator::Rk4);
    assert_eq!(p.kinematic_branch, KinematicBranch::Main);
    assert!(p.effects.all_off());
    p.validate().unwrap();
}

#[test]
fn yaml_round_trip_with_every_effect() {
    let mut p = VehicleParams {
        mu: 0.9,
        m: 3.5,
        model: VehicleModel::Ks,
        integrator: Integrator::Euler,
        kinematic_branch: KinematicBranch::V1,
        ..Default::default()
    };
    p.effects = Effects {
        steering_delay: Some(SteeringDelay { delay_s: 0.04 }),
        steering_lag: Some(FirstOrderLag { tau_s: 0.05 }),
        steering_offset: Some(SteeringOffset { offset_rad: -0.01 }),
        drive_lag: Some(FirstOrderLag { tau_s: 0.2 }),
        drag: Some(Drag {
            c_lin: 0.1,
            c_quad: 0.02,
        }),
        friction_patch: Some(vec![FrictionPatch {
            mu: 0.6,
            region: [0.0, -1.0, 5.0, 1.0],
        }]),
        tire_saturation: Some(TireSaturation {
            d: 1.0,
            c: 1.3,
            e: -0.5,
        }),
        steering_gain: Some(SteeringGain { gain: 0.9 }),
        speed_gain: Some(SpeedGain { gain: 1.05 }),
        steering_backlash: Some(SteeringBacklash { width_rad: 0.03 }),
    };
    let text = p.to_yaml_string();
    assert!(text.contains("C_Sf:"), "{text}");
    assert!(text.contains("D: 1.0"), "{text}");
    let back = VehicleParams::from_yaml_str(&text).unwrap();
    assert_eq!(back, p);
    // Defaults omit the effects block entirely.
    let d = VehicleParams::default().to_yaml_string();
    assert!(!d.contains("effects"), "{d}");
    assert_eq!(
        VehicleParams::from_yaml_str(&d).unwrap(),
        VehicleParams::default()
    );
}

#[test]
fn missing_keys_default_and_nested_params_accepted() {
    let p = VehicleParams::from_yaml_str("mu: 0.8\nI: 0.05\n").unwrap();
    assert_eq!(p.mu, 0.8);
    assert_eq!(p.inertia, 0.05);
    assert_eq!(p.m, 3.74);
    let q = VehicleParams::from_yaml_str("params:\n  mu: 0.8\n  I: 0.05\n").unwrap();
    assert_eq!(p, q);
    assert_eq!(
        VehicleParams::from_yaml_str("# nothing\n").unwrap(),
        VehicleParams::default()
    );
    let e = VehicleParams::from_yaml_str("effects:\n  drag: {c_lin: 0.5, c_quad: 0.0}\n")
        .unwrap()
        .effects;
    assert_eq!(e.drag.unwrap().c_lin, 0.5);
    assert!(e.steering_delay.is_none());
}

#[test]
fn later_documents_override_earlier_ones() {
    let base = VehicleParams {
        mu: 0.9,
        m: 3.0,
        effects: Effects {
            drag: Some(Drag {
                c_lin: 0.1,
                c_quad: 0.0,
            }),
            ..Default::default()
        },
        ..Default::default()
    };
    let text = format!("{}---\nm: 4.25\nI: 0.05\n", base.to_yaml_string());
    let p = VehicleParams::from_yaml_str(&text).unwrap();
    assert_eq!((p.mu, p.m, p.inertia), (0.9, 4.25, 0.05));
    assert_eq!(p.effects, base.effects);
    let nested = VehicleParams::from_yaml_str("params:\n  mu: 0.7\n---\nmu: 0.8\n").unwrap();
    assert_eq!(nested.mu, 0.8);
    // an override is checked like any key: unknown names and bad values are refused
    let e = VehicleParams::from_yaml_str("mu: 0.9\n---\nmass: 3.0\n").unwrap_err();
    assert!(e.to_string().contains("mass"), "{e}");
    let e = VehicleParams::from_yaml_str("mu: 0.9\n---\nm: -1.5\n").unwrap_err();
    assert_eq!(e.field(), Some("m"), "{e}");
    assert!(e.to_string().contains("-1.5"), "{e}");
}

#[test]
fn unknown_keys_are_rejected() {
    for bad in [
        "mu: 1.0\nmass: 3.0\n",
        "params:\n  mu: 1.0\n  muu: 2.0\n",
        "params:\n  mu: 1.0\nextra: 1\n",
        "effects:\n  drag: {c_lin: 0.1, c_quad: 0.0, c_cube: 1.0}\n",
        "effects:\n  wind: {speed: 3}\n",
        "model: dynamic\n",
    ] {
        let err = VehicleParams::from_yaml_str(bad).unwrap_err();
        assert!(matches!(err, ParamsError::Yaml { .. }), "{bad}: {err}");
    }
    let err = VehicleParams::from_yaml_str("mu: 1.0\nmass: 3.0\n").unwrap_err();
    assert!(err.to_string().contains("mass"), "{err}");
}

#[test]
fn validation_errors_name_the_field_and_value() {
    let cases: Vec<(VehicleParams, &str, &str)> = vec![
        (
            VehicleParams {
                m: 0.0,
                ..Default::default()
            },
            "m",
            "0",
        ),
        (
            VehicleParams {
                mu: f64::NAN,
                ..Default::default()
            },
            "mu",
            "NaN",
        ),
        (
            VehicleParams {
                c_sf: f64::INFINITY,
                ..Default::default()
            },
            "C_Sf",
            "inf",
        ),
        (
            VehicleParams {
                s_min: 0.5,
                ..Default::default()
            },
            "s_min",
            "0.5",
        ),
        (
            VehicleParams {
                effects: Effects {
                    steering_lag: Some(FirstOrderLag { tau_s: -0.1 }),
                    ..Default::default()
                },
                ..Default::default()
            },
            "effects.steering_lag.tau_s",
            "-0.1",
        ),
        (
            VehicleParams {
                effects: Effects {
                    friction_patch: Some(vec![
                        FrictionPatch {
                            mu: 0.5,
                            region: [0.0, 0.0, 1.0, 1.0],
                        },
                        FrictionPatch {
                            mu: 0.5,
                            region: [0.0, 0.0, -1.0, 1.0],
                        },
                    ]),
                    ..Default::default()
                },
                ..Default::default()
            },
            "effects.friction_patch[1].region[2]",
            "-1",
        ),
    ];
    for (p, field, value) in cases {
        let err = p.validate().unwrap_err();
        assert_eq!(err.field(), Some(field), "{err}");
        let msg = err.to_string();
        assert!(msg.contains(field) && msg.contains(value), "{msg}");
    }
    // Loading validates too.
    let err = VehicleParams::from_yaml_str("m: -1.0\n").unwrap_err();
    assert_eq!(err.field(), Some("m"), "{err}");
}

#[test]
fn load_reports_the_path() {
    let err = VehicleParams::load("does/not/exist.yaml").unwrap_err();
    assert!(err.to_string().contains("exist.yaml"), "{err}");
}
