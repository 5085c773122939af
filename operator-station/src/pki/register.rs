//! The fleet register (`fleet.toml` in the PKI folder): every robot and monitor certificate
//! issued, and which are revoked. The station admits, per robot and per monitor, only its newest
//! certificate that is not revoked; a superseded or revoked certificate's common name matches none
//! of its access rules.

use common::keys::RobotId;
use common::security::{AdmittedMonitor, AdmittedRobot};
use serde::{Deserialize, Serialize};

/// One issued robot certificate.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Issued {
    /// Robot id.
    pub robot: String,
    /// Issue number of this robot (1, 2, ...): part of the common name.
    pub serial: u32,
    /// The certificate's common name (`terranav:robot:<id>:<serial>`).
    pub cn: String,
    /// When issued, Unix seconds.
    pub issued_unix_s: i64,
    /// End of validity, Unix seconds.
    pub not_after_unix_s: i64,
    /// When revoked, Unix seconds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub revoked_unix_s: Option<i64>,
}

/// One issued monitor certificate (a read-only station: `pki add-monitor`).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct IssuedMonitor {
    /// Monitor name.
    pub name: String,
    /// Issue number of this monitor (1, 2, ...): part of the common name.
    pub serial: u32,
    /// The certificate's common name (`terranav:monitor:<name>:<serial>`).
    pub cn: String,
    /// When issued, Unix seconds.
    pub issued_unix_s: i64,
    /// End of validity, Unix seconds.
    pub not_after_unix_s: i64,
    /// When revoked, Unix seconds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub revoked_unix_s: Option<i64>,
}

/// The register.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Register {
    /// Every robot certificate ever issued, oldest first.
    #[serde(default, rename = "robot")]
    pub robots: Vec<Issued>,
    /// Every monitor certificate ever issued, oldest first.
    #[serde(default, rename = "monitor", skip_serializing_if = "Vec::is_empty")]
    pub monitors: Vec<IssuedMonitor>,
}

impl Register {
    /// Parses `fleet.toml`.
    pub fn parse(text: &str) -> Result<Self, String> {
        toml::from_str(text).map_err(|e| e.to_string())
    }

    /// The file's text.
    pub fn to_text(&self) -> String {
        let body = toml::to_string(self).unwrap_or_default();
        format!(
            "# Written by `operator-station pki`: every robot and monitor certificate issued and \
             which are revoked.\n# The station admits each robot's and monitor's newest \
             certificate that is not revoked; it re-reads this file when it changes.\n\n{body}"
        )
    }

    /// The next issue number of `robot`.
    pub fn next_serial(&self, robot: &RobotId) -> u32 {
        self.robots
            .iter()
            .filter(|i| i.robot == robot.as_str())
            .map(|i| i.serial)
            .max()
            .unwrap_or(0)
            + 1
    }

    /// The newest certificate of `robot`, if any.
    pub fn newest(&self, robot: &str) -> Option<&Issued> {
        self.robots
            .iter()
            .filter(|i| i.robot == robot)
            .max_by_key(|i| i.serial)
    }

    /// Marks every certificate of `robot` revoked at `now_unix_s`; returns how many were valid.
    pub fn revoke(&mut self, robot: &RobotId, now_unix_s: i64) -> usize {
        let mut n = 0;
        for i in self
            .robots
            .iter_mut()
            .filter(|i| i.robot == robot.as_str() && i.revoked_unix_s.is_none())
        {
            i.revoked_unix_s = Some(now_unix_s);
            n += 1;
        }
        n
    }

    /// The robots the station admits at `now_unix_s`: each robot's newest certificate, unless it is
    /// revoked or expired. Bad ids in a hand-edited file are skipped.
    pub fn admitted(&self, now_unix_s: i64) -> Vec<AdmittedRobot> {
        let mut ids: Vec<&str> = self.robots.iter().map(|i| i.robot.as_str()).collect();
        ids.sort_unstable();
        ids.dedup();
        ids.into_iter()
            .filter_map(|id| {
                let i = self.newest(id)?;
                if i.revoked_unix_s.is_some() || i.not_after_unix_s < now_unix_s {
                    return None;
                }
                Some(AdmittedRobot {
                    robot: RobotId::new(id).ok()?,
                    cn: i.cn.clone(),
                })
            })
            .collect()
    }

    /// The next issue number of monitor `name`.
    pub fn next_monitor_serial(&self, name: &str) -> u32 {
        self.monitors
            .iter()
            .filter(|i| i.name == name)
            .map(|i| i.serial)
            .max()
            .unwrap_or(0)
            + 1
    }

    /// The newest certificate of monitor `name`, if any.
    pub fn newest_monitor(&self, name: &str) -> Option<&IssuedMonitor> {
        self.monitors
            .iter()
            .filter(|i| i.name == name)
            .max_by_key(|i| i.serial)
    }

    /// Marks every certificate of monitor `name` revoked; returns how many were valid.
    pub fn revoke_monitor(&mut self, name: &str, now_unix_s: i64) -> usize {
        let mut n = 0;
        for i in self
            .monitors
            .iter_mut()
            .filter(|i| i.name == name && i.revoked_unix_s.is_none())
        {
            i.revoked_unix_s = Some(now_unix_s);
            n += 1;
        }
        n
    }

    /// The monitors the station admits at `now_unix_s`: each one's newest certificate, unless it
    /// is revoked or expired. Bad names in a hand-edited file are skipped.
    pub fn admitted_monitors(&self, now_unix_s: i64) -> Vec<AdmittedMonitor> {
        let mut names: Vec<&str> = self.monitors.iter().map(|i| i.name.as_str()).collect();
        names.sort_unstable();
        names.dedup();
        names
            .into_iter()
            .filter(|n| common::security::check_monitor_name(n).is_ok())
            .filter_map(|n| {
                let i = self.newest_monitor(n)?;
                if i.revoked_unix_s.is_some() || i.not_after_unix_s < now_unix_s {
                    return None;
                }
                Some(AdmittedMonitor {
                    name: n.to_string(),
                    cn: i.cn.clone(),
                })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn issued(robot: &str, serial: u32) -> Issued {
        Issued {
            robot: robot.into(),
            serial,
            cn: format!("terranav:robot:{robot}:{serial}"),
            issued_unix_s: 100,
            not_after_unix_s: 1000,
            revoked_unix_s: None,
        }
    }

    #[test]
    fn newest_unrevoked_certificate_is_admitted_only() {
        let mut r = Register {
            robots: vec![issued("a", 1), issued("a", 2), issued("b", 1)],
            monitors: Vec::new(),
        };
        let cns = |r: &Register, now| -> Vec<String> {
            r.admitted(now).into_iter().map(|a| a.cn).collect()
        };
        assert_eq!(
            cns(&r, 500),
            ["terranav:robot:a:2", "terranav:robot:b:1"],
            "a's first certificate is superseded"
        );
        assert_eq!(r.revoke(&RobotId::new("a").unwrap(), 600), 2);
        assert_eq!(cns(&r, 700), ["terranav:robot:b:1"]);
        assert!(cns(&r, 2000).is_empty(), "expired");
        // Re-issuing after a revocation admits the new certificate, never the revoked ones.
        let a = RobotId::new("a").unwrap();
        assert_eq!(r.next_serial(&a), 3);
        r.robots.push(issued("a", 3));
        assert_eq!(cns(&r, 700), ["terranav:robot:a:3", "terranav:robot:b:1"]);
        let back = Register::parse(&r.to_text()).unwrap();
        assert_eq!(back, r);
    }

    #[test]
    fn newest_unrevoked_monitor_is_admitted_only_and_robots_are_untouched() {
        let m = |name: &str, serial| IssuedMonitor {
            name: name.into(),
            serial,
            cn: common::security::monitor_cn(name, serial),
            issued_unix_s: 100,
            not_after_unix_s: 1000,
            revoked_unix_s: None,
        };
        let mut r = Register {
            robots: vec![issued("a", 1)],
            monitors: vec![m("ops", 1), m("ops", 2), m("hq", 1)],
        };
        let cns = |r: &Register, now| -> Vec<String> {
            r.admitted_monitors(now).into_iter().map(|a| a.cn).collect()
        };
        assert_eq!(
            cns(&r, 500),
            ["terranav:monitor:hq:1", "terranav:monitor:ops:2"]
        );
        assert_eq!(r.next_monitor_serial("ops"), 3);
        assert_eq!(r.revoke_monitor("ops", 600), 2);
        assert_eq!(cns(&r, 700), ["terranav:monitor:hq:1"]);
        assert_eq!(r.admitted(700).len(), 1, "robots are not touched");
        assert!(cns(&r, 2000).is_empty(), "expired");
        let back = Register::parse(&r.to_text()).unwrap();
        assert_eq!(back, r);
        // A register written before monitors existed still reads.
        let old = Register::parse("[[robot]]\nrobot = \"a\"\nserial = 1\ncn = \"terranav:robot:a:1\"\nissued_unix_s = 1\nnot_after_unix_s = 9\n").unwrap();
        assert!(old.monitors.is_empty() && old.robots.len() == 1);
    }
}
