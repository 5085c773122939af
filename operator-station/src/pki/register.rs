//! The fleet register (`fleet.toml` in the PKI folder): every robot and monitor certificate
//! issued, and which are revoked. The station admits, per robot and per monitor, only its newest
//! certificate that is not revoked; a superseded or revoked certificate's common name matches none
//! of its access rules.

use common::keys::RobotId;
use common::security::{AdmittedMonitor, AdmittedRobot};
use serde::{Deserialize, Serialize};

/// Whom a leaf certificate names: a robot, or a monitor (a read-only station, `pki add-monitor`).
/// Both follow one life cycle in the register: numbered issues, the newest unrevoked one admitted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A robot (`terranav:robot:<id>:<serial>`).
    Robot,
    /// A monitor (`terranav:monitor:<name>:<serial>`).
    Monitor,
}

impl Kind {
    /// The word for messages (`robot`, `monitor`).
    pub fn noun(self) -> &'static str {
        match self {
            Kind::Robot => "robot",
            Kind::Monitor => "monitor",
        }
    }
}

/// One issued certificate.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Issued {
    /// Robot id or monitor name. Registers written before monitors existed name it `robot`,
    /// monitors' entries named it `name`; both still read.
    #[serde(alias = "robot", alias = "name")]
    pub id: String,
    /// Issue number for this id (1, 2, ...): part of the common name.
    pub serial: u32,
    /// The certificate's common name (`terranav:<kind>:<id>:<serial>`).
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
    pub monitors: Vec<Issued>,
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

    /// The certificates of one kind, oldest first.
    pub fn entries(&self, kind: Kind) -> &[Issued] {
        match kind {
            Kind::Robot => &self.robots,
            Kind::Monitor => &self.monitors,
        }
    }

    /// Records a newly issued certificate.
    pub fn push(&mut self, kind: Kind, issued: Issued) {
        match kind {
            Kind::Robot => self.robots.push(issued),
            Kind::Monitor => self.monitors.push(issued),
        }
    }

    /// The next issue number of `id`.
    pub fn next_serial(&self, kind: Kind, id: &str) -> u32 {
        self.newest(kind, id).map_or(0, |i| i.serial) + 1
    }

    /// The newest certificate of `id`, if any.
    pub fn newest(&self, kind: Kind, id: &str) -> Option<&Issued> {
        self.entries(kind)
            .iter()
            .filter(|i| i.id == id)
            .max_by_key(|i| i.serial)
    }

    /// Marks every certificate of `id` revoked at `now_unix_s`; returns how many were valid.
    pub fn revoke(&mut self, kind: Kind, id: &str, now_unix_s: i64) -> usize {
        let list = match kind {
            Kind::Robot => &mut self.robots,
            Kind::Monitor => &mut self.monitors,
        };
        let mut n = 0;
        for i in list
            .iter_mut()
            .filter(|i| i.id == id && i.revoked_unix_s.is_none())
        {
            i.revoked_unix_s = Some(now_unix_s);
            n += 1;
        }
        n
    }

    /// Each id's newest certificate of one kind at `now_unix_s`, unless it is revoked or expired:
    /// `(id, common name)`, sorted by id.
    fn admitted_of(&self, kind: Kind, now_unix_s: i64) -> Vec<(&str, String)> {
        let mut ids: Vec<&str> = self.entries(kind).iter().map(|i| i.id.as_str()).collect();
        ids.sort_unstable();
        ids.dedup();
        ids.into_iter()
            .filter_map(|id| {
                let i = self.newest(kind, id)?;
                (i.revoked_unix_s.is_none() && i.not_after_unix_s >= now_unix_s)
                    .then(|| (id, i.cn.clone()))
            })
            .collect()
    }

    /// The robots the station admits at `now_unix_s`. Bad ids in a hand-edited file are skipped.
    pub fn admitted(&self, now_unix_s: i64) -> Vec<AdmittedRobot> {
        self.admitted_of(Kind::Robot, now_unix_s)
            .into_iter()
            .filter_map(|(id, cn)| {
                Some(AdmittedRobot {
                    robot: RobotId::new(id).ok()?,
                    cn,
                })
            })
            .collect()
    }

    /// The monitors the station admits at `now_unix_s`. Bad names in a hand-edited file are
    /// skipped.
    pub fn admitted_monitors(&self, now_unix_s: i64) -> Vec<AdmittedMonitor> {
        self.admitted_of(Kind::Monitor, now_unix_s)
            .into_iter()
            .filter(|(n, _)| common::security::check_monitor_name(n).is_ok())
            .map(|(n, cn)| AdmittedMonitor {
                name: n.to_string(),
                cn,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn issued(robot: &str, serial: u32) -> Issued {
        Issued {
            id: robot.into(),
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
        assert_eq!(r.revoke(Kind::Robot, "a", 600), 2);
        assert_eq!(cns(&r, 700), ["terranav:robot:b:1"]);
        assert!(cns(&r, 2000).is_empty(), "expired");
        // Re-issuing after a revocation admits the new certificate, never the revoked ones.
        assert_eq!(r.next_serial(Kind::Robot, "a"), 3);
        r.robots.push(issued("a", 3));
        assert_eq!(cns(&r, 700), ["terranav:robot:a:3", "terranav:robot:b:1"]);
        let back = Register::parse(&r.to_text()).unwrap();
        assert_eq!(back, r);
    }

    #[test]
    fn newest_unrevoked_monitor_is_admitted_only_and_robots_are_untouched() {
        let m = |name: &str, serial| Issued {
            id: name.into(),
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
        assert_eq!(r.next_serial(Kind::Monitor, "ops"), 3);
        assert_eq!(r.revoke(Kind::Monitor, "ops", 600), 2);
        assert_eq!(cns(&r, 700), ["terranav:monitor:hq:1"]);
        assert_eq!(r.admitted(700).len(), 1, "robots are not touched");
        assert!(cns(&r, 2000).is_empty(), "expired");
        let back = Register::parse(&r.to_text()).unwrap();
        assert_eq!(back, r);
        // A register written before monitors existed still reads.
        let old = Register::parse("[[robot]]\nrobot = \"a\"\nserial = 1\ncn = \"terranav:robot:a:1\"\nissued_unix_s = 1\nnot_after_unix_s = 9\n").unwrap();
        assert!(old.monitors.is_empty() && old.robots.len() == 1);
        assert_eq!(old.robots[0].id, "a");
        let m = Register::parse("[[monitor]]\nname = \"ops\"\nserial = 1\ncn = \"terranav:monitor:ops:1\"\nissued_unix_s = 1\nnot_after_unix_s = 9\n").unwrap();
        assert_eq!(m.monitors[0].id, "ops");
    }
}
