//! Every key of every shipped TOML file is read (issue 23): each leaf value is changed in turn
//! and the file loaded the way the product loads it; the loaded configuration must differ (or
//! the loader must refuse the new value, which also proves the key is read). A key that is
//! parsed but then overwritten by another file (the robot profile's sensor mount written into
//! the SLAM and mapper parts, say) or ignored fails here with its file and path.

use robot_agent::config::{load, load_agent_config, load_run_file};
use std::path::{Path, PathBuf};

fn shipped() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../config")
}

/// Paths of every leaf value (`section.key`, `ramp[2].slope_deg`, `points[0]`).
fn leaves(v: &toml::Value, path: String, out: &mut Vec<String>) {
    match v {
        toml::Value::Table(t) => {
            for (k, v) in t {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                leaves(v, p, out);
            }
        }
        toml::Value::Array(a) if !a.is_empty() => {
            // Every table of an array of tables; the first element of a list of values (a
            // list is one setting).
            let all = a.iter().all(toml::Value::is_table);
            for (i, v) in a.iter().enumerate().take(if all { a.len() } else { 1 }) {
                leaves(v, format!("{path}[{i}]"), out);
            }
        }
        // An empty list has no element whose type says what a different value would be.
        toml::Value::Array(_) => {}
        _ => out.push(path),
    }
}

fn get_mut<'a>(v: &'a mut toml::Value, path: &str) -> &'a mut toml::Value {
    let mut cur = v;
    for part in path.split('.') {
        // `name[i][j]`: a table key then one index per nesting level.
        let mut pieces = part.split('[');
        let name = pieces.next().unwrap_or_default();
        cur = cur
            .get_mut(name)
            .unwrap_or_else(|| panic!("{path}: no {name}"));
        for i in pieces {
            let i: usize = i.trim_end_matches(']').parse().unwrap();
            cur = cur.get_mut(i).unwrap();
        }
    }
    cur
}

/// A different value of the same type.
fn perturb(v: &mut toml::Value) {
    *v = match v {
        toml::Value::Integer(i) => toml::Value::Integer(*i + 1),
        toml::Value::Float(f) => toml::Value::Float(*f * 1.37 + 0.011),
        toml::Value::Boolean(b) => toml::Value::Boolean(!*b),
        toml::Value::String(s) => toml::Value::String(format!("{s}x")),
        toml::Value::Array(a) => {
            let mut a = a.clone();
            if let Some(first) = a.first_mut() {
                perturb(first);
            }
            toml::Value::Array(a)
        }
        other => panic!("cannot perturb {other:?}"),
    };
}

/// For every leaf of `file` (in `config/`): writes the folder with that value changed into a
/// temporary copy and checks `describe` (the loaded configuration, or the loader's error)
/// changes. Returns the keys that made no difference.
fn unread_keys(file: &str, describe: impl Fn(&Path) -> String) -> Vec<String> {
    let dir = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(shipped()).unwrap().flatten() {
        if e.path().extension().is_some_and(|x| x == "toml") {
            std::fs::copy(e.path(), dir.path().join(e.file_name())).unwrap();
        }
    }
    let target = dir.path().join(file);
    let text = std::fs::read_to_string(shipped().join(file)).unwrap();
    let base: toml::Value = toml::from_str(&text).unwrap();
    std::fs::write(&target, &text).unwrap();
    let before = describe(dir.path());
    assert!(!before.starts_with("Err"), "{file} does not load: {before}");
    let mut paths = Vec::new();
    leaves(&base, String::new(), &mut paths);
    assert!(!paths.is_empty(), "{file}: no keys");
    let mut unread = Vec::new();
    for p in paths {
        let mut v = base.clone();
        perturb(get_mut(&mut v, &p));
        std::fs::write(&target, toml::to_string(&v).unwrap()).unwrap();
        if describe(dir.path()) == before {
            unread.push(p);
        }
    }
    unread
}

fn agent(dir: &Path) -> String {
    match load_agent_config(dir) {
        Ok(c) => format!("{c:?}"),
        Err(e) => format!("Err {e}"),
    }
}

#[test]
fn every_key_of_the_agent_files_is_read() {
    let mut unread = Vec::new();
    for f in [
        "slam.toml",
        "mapper.toml",
        "planner.toml",
        "control.toml",
        "mission.toml",
    ] {
        unread.extend(
            unread_keys(f, agent)
                .into_iter()
                .map(|k| format!("{f}: {k}")),
        );
    }
    // robot.toml: the profile and the run sections, read by two loaders.
    unread.extend(
        unread_keys("robot.toml", |d| {
            let run = load_run_file(&d.join("robot.toml"))
                .map(|r| format!("{:?} {:?} {:?}", r.io, r.runtime, r.bus.uplink(None)))
                .unwrap_or_else(|e| format!("Err {e}"));
            format!("{} {run}", agent(d))
        })
        .into_iter()
        .map(|k| format!("robot.toml: {k}")),
    );
    assert!(unread.is_empty(), "keys that change nothing: {unread:#?}");
}

#[test]
fn every_key_of_the_alternative_files_and_worlds_is_read() {
    fn typed<T: serde::de::DeserializeOwned + Default + std::fmt::Debug>(
        name: &'static str,
    ) -> impl Fn(&Path) -> String {
        move |d: &Path| match load::<T>(d, name) {
            Ok(c) => format!("{c:?}"),
            Err(e) => format!("Err {e}"),
        }
    }
    let mut unread = Vec::new();
    let mut check =
        |f: &str, u: Vec<String>| unread.extend(u.into_iter().map(|k| format!("{f}: {k}")));
    check(
        "mapper-car.toml",
        unread_keys(
            "mapper-car.toml",
            typed::<robot_agent::mapping::Config>("mapper-car.toml"),
        ),
    );
    check(
        "slam-kitti.toml",
        unread_keys(
            "slam-kitti.toml",
            typed::<robot_agent::slam::Config>("slam-kitti.toml"),
        ),
    );
    check(
        "slam-pair.toml",
        unread_keys(
            "slam-pair.toml",
            typed::<robot_agent::slam::Config>("slam-pair.toml"),
        ),
    );
    for e in std::fs::read_dir(shipped().join("scenarios"))
        .unwrap()
        .flatten()
    {
        let name = format!("scenarios/{}", e.file_name().to_string_lossy());
        let u = unread_keys_in(&e.path(), |p| match robot_agent::sim::Scenario::load(p) {
            Ok(s) => format!("{s:?}"),
            Err(e) => format!("Err {e}"),
        });
        check(&name, u);
    }
    let obstacles = shipped().join("obstacles/teach-route.toml");
    let u = unread_keys_in(&obstacles, |p| {
        match robot_agent::run::ObstacleFile::load(p) {
            Ok(o) => format!("{:?}", o.obstacles()),
            Err(e) => format!("Err {e}"),
        }
    });
    check("obstacles/teach-route.toml", u);
    assert!(unread.is_empty(), "keys that change nothing: {unread:#?}");
}

/// [`unread_keys`] for a file loaded on its own (a scenario), by its path.
fn unread_keys_in(file: &Path, describe: impl Fn(&Path) -> String) -> Vec<String> {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join(file.file_name().unwrap());
    let text = std::fs::read_to_string(file).unwrap();
    let base: toml::Value = toml::from_str(&text).unwrap();
    std::fs::write(&target, &text).unwrap();
    let before = describe(&target);
    assert!(!before.starts_with("Err"), "{}: {before}", file.display());
    let mut paths = Vec::new();
    leaves(&base, String::new(), &mut paths);
    let mut unread = Vec::new();
    for p in paths {
        let mut v = base.clone();
        perturb(get_mut(&mut v, &p));
        std::fs::write(&target, toml::to_string(&v).unwrap()).unwrap();
        if describe(&target) == before {
            unread.push(p);
        }
    }
    unread
}
