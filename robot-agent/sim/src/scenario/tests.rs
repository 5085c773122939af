use super::*;

const MIN: &str = r#"
name = "t"
[datum]
lat_deg = 48.0
lon_deg = 16.0
h_m = 200.0
[extent]
x_min_m = -10.0
x_max_m = 10.0
y_min_m = -10.0
y_max_m = 10.0
"#;

#[test]
fn minimal_loads() {
    let s = Scenario::from_toml_str(MIN, "x").unwrap();
    assert_eq!(s.terrain.resolution_m, 0.05);
    assert!(s.walker.is_empty());
}

#[test]
fn unknown_field_is_named() {
    let e = Scenario::from_toml_str(
        &format!("{MIN}\n[[pole]]\nx_m = 1.0\ny_m = 2.0\nradiuss_m = 3.0\n"),
        "x",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("radiuss_m"), "{e}");
}

#[test]
fn bad_value_is_named() {
    let e = Scenario::from_toml_str(
        &format!("{MIN}\n[[ramp]]\nx_m = 0.0\ny_m = 0.0\nyaw_deg = 0.0\nslope_deg = 95.0\nwidth_m = 2.0\nlength_m = 3.0\n"),
        "x",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("ramp[0].slope_deg"), "{e}");
    let e = Scenario::from_toml_str(
        &MIN.replace("resolution_m", "x")
            .replace("[extent]", "[terrain]\nresolution_m = 0.1\n[extent]"),
        "x",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("terrain.resolution_m"), "{e}");
}

#[test]
fn all_scenario_files_load() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/scenarios");
    let mut n = 0;
    let mut entries: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .collect();
    entries.sort();
    for p in entries {
        if p.extension().is_some_and(|e| e == "toml") {
            let s = Scenario::load(&p).unwrap_or_else(|e| panic!("{e}"));
            assert!(!s.name.is_empty());
            n += 1;
        }
    }
    assert!(n >= 5, "{n} scenarios");
}
