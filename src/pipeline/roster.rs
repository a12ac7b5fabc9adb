//! Which cameras are in the rig (camera dropout).
//!
//! A camera that has sent nothing for `camera_timeout` (measured on the clock the caller
//! passes: receive time live, log time in a bag) leaves the rig; sets go on with the others
//! while at least 2 remain and the reference is among them. A camera that sends again rejoins
//! at once. The synchroniser runs over the cameras in the rig: its stream `k` is camera
//! `active[k]`.

use std::time::Duration;

use super::outcome::{Degraded, RigEvent};

#[derive(Debug, Clone)]
pub(super) struct Roster {
    names: Vec<String>,
    /// The reference cameras (`references`): sets are formed while one of them is in the rig.
    references: Vec<usize>,
    timeout: Option<Duration>,
    /// The cameras in the rig, in rig order.
    active: Vec<usize>,
    last_seen_ns: Vec<Option<u64>>,
    /// Per camera, its first [`GAPS`] gaps between images, and whether they were judged
    /// ([`Roster::too_slow`]).
    gaps_ns: Vec<Vec<u64>>,
    said_slow: Vec<bool>,
    first_ns: Option<u64>,
}

/// Gaps between a camera's images that [`Roster::too_slow`] judges its frame period by.
const GAPS: usize = 5;

impl Roster {
    pub fn new(names: Vec<String>, references: Vec<usize>, timeout: Option<Duration>) -> Self {
        let n = names.len();
        Self {
            names,
            references,
            timeout,
            active: (0..n).collect(),
            last_seen_ns: vec![None; n],
            gaps_ns: vec![Vec::with_capacity(GAPS); n],
            said_slow: vec![false; n],
            first_ns: None,
        }
    }

    /// The cameras in the rig, in rig order (synchroniser stream `k` is camera `active()[k]`).
    pub fn active(&self) -> &[usize] {
        &self.active
    }

    /// The synchroniser stream of camera `camera`, if it is in the rig.
    pub fn stream_of(&self, camera: usize) -> Option<usize> {
        self.active.iter().position(|&a| a == camera)
    }

    /// The camera of synchroniser stream `stream`.
    pub fn camera_of(&self, stream: usize) -> usize {
        self.active.get(stream).copied().unwrap_or(stream)
    }

    /// Sets are formed: a reference and at least one other camera are in the rig.
    pub fn publishing(&self) -> bool {
        self.references.iter().any(|r| self.active.contains(r)) && self.active.len() >= 2
    }

    /// Names of the cameras out of the rig.
    pub fn inactive(&self) -> Vec<String> {
        (0..self.names.len())
            .filter(|i| !self.active.contains(i))
            .map(|i| self.names[i].clone())
            .collect()
    }

    /// Once per camera, when its frame period (the median of its first [`GAPS`] gaps between
    /// images) is more than half of `camera_timeout`: an image half a period late then takes
    /// it out of the rig (a 1 Hz capture rig with the default 1 s). The period and the timeout,
    /// in seconds.
    pub fn too_slow(&mut self, camera: usize) -> Option<(f64, f64)> {
        let timeout = self.timeout?;
        let gaps = self.gaps_ns.get(camera)?;
        if self.said_slow[camera] || gaps.len() < GAPS {
            return None;
        }
        let mut sorted = gaps.clone();
        sorted.sort_unstable();
        let period_s = sorted[GAPS / 2] as f64 * 1e-9;
        let timeout_s = timeout.as_secs_f64();
        self.said_slow[camera] = true;
        (2.0 * period_s > timeout_s).then_some((period_s, timeout_s))
    }

    /// Camera `camera` sent something at `now_ns`: it is (back) in the rig, and every camera
    /// silent for longer than the timeout leaves it. Returns what changed.
    pub fn track(&mut self, camera: usize, now_ns: u64) -> Vec<RigEvent> {
        let n = self.names.len();
        let first = *self.first_ns.get_or_insert(now_ns);
        // Its first gaps alone: [`Roster::too_slow`] judges them once.
        if let (Some(last), false) = (self.last_seen_ns[camera], self.said_slow[camera]) {
            let gaps = &mut self.gaps_ns[camera];
            if gaps.len() < GAPS {
                gaps.push(now_ns.saturating_sub(last));
            }
        }
        self.last_seen_ns[camera] = Some(now_ns);
        let mut events = Vec::new();
        if !self.active.contains(&camera) {
            self.active.push(camera);
            self.active.sort_unstable();
            events.push(RigEvent::Rejoined {
                camera: self.names[camera].clone(),
                active: self.active.len(),
                total: n,
            });
        }
        let Some(timeout) = self.timeout else {
            return events;
        };
        let timeout_ns = u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX);
        let silent: Vec<(usize, u64)> = self
            .active
            .iter()
            .map(|&j| {
                (
                    j,
                    now_ns.saturating_sub(self.last_seen_ns[j].unwrap_or(first)),
                )
            })
            .filter(|&(_, quiet)| quiet > timeout_ns)
            .collect();
        for (j, quiet) in silent {
            self.active.retain(|&a| a != j);
            let no_reference = !self.references.iter().any(|r| self.active.contains(r));
            let then = if no_reference && self.references.contains(&j) {
                Degraded::ReferenceLost
            } else if no_reference {
                Degraded::ReferenceStillOut
            } else if self.active.len() < 2 {
                Degraded::TooFew
            } else {
                Degraded::GoingOn(self.active.len())
            };
            events.push(RigEvent::Left {
                camera: self.names[j].clone(),
                quiet_s: quiet as f64 * 1e-9,
                timeout_s: timeout.as_secs_f64(),
                then,
            });
        }
        events
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn silent_cameras_leave_and_rejoin() {
        let names = vec!["a".to_string(), "b".into(), "c".into()];
        let mut r = Roster::new(names, vec![1], Some(Duration::from_millis(250)));
        for t in [0, 100, 200] {
            for i in 0..3 {
                assert!(r.track(i, t * MS).is_empty());
            }
        }
        // c stops; after 250 ms it leaves, the others go on.
        assert!(r.track(0, 400 * MS).is_empty());
        assert!(r.track(1, 400 * MS).is_empty());
        let events = r.track(0, 480 * MS);
        assert_eq!(events.len(), 1, "{events:?}");
        assert_eq!(
            events[0].to_string(),
            "camera 'c' has sent nothing for 0.28 s (camera_timeout 0.25 s) and leaves the rig; going on with the other 2"
        );
        assert!(r.publishing());
        assert_eq!(r.active(), &[0, 1]);
        assert_eq!(r.inactive(), vec!["c".to_string()]);
        assert_eq!(r.stream_of(1), Some(1));
        assert_eq!(r.stream_of(2), None);
        // c is back: stream 2 again.
        let events = r.track(2, 490 * MS);
        assert_eq!(
            events[0].to_string(),
            "camera 'c' is sending again and is back in the rig (3 of 3 cameras)"
        );
        assert_eq!(r.stream_of(2), Some(2));
        // The reference b stops: nothing is published.
        let events = r.track(0, 700 * MS);
        assert_eq!(events.len(), 1, "{events:?}");
        assert!(events[0]
            .to_string()
            .contains("it is the reference camera: no depth is published"));
        assert!(!r.publishing());
        // c stops too: it is not the reference, and says the reference is out.
        let events = r.track(0, 760 * MS);
        assert_eq!(events.len(), 1, "{events:?}");
        let said = events[0].to_string();
        assert!(
            said.starts_with("camera 'c' ")
                && said.ends_with("the reference camera is out of the rig too: no depth is published until it is back")
                && !said.contains("it is the reference camera"),
            "{said}"
        );
    }

    /// A 1 Hz camera with the default 1 s timeout is said to be too slow for it, once, after
    /// its first five gaps; a 10 Hz one is not.
    #[test]
    fn a_camera_slower_than_half_the_timeout_is_said_once() {
        let mut r = Roster::new(
            vec!["a".into(), "b".into()],
            vec![0],
            Some(Duration::from_secs(1)),
        );
        for k in 0..20u64 {
            r.track(0, k * 100 * MS);
            assert_eq!(r.too_slow(0), None, "10 Hz");
        }
        let mut said = Vec::new();
        for k in 0..8u64 {
            r.track(1, k * 1000 * MS);
            said.extend(r.too_slow(1));
        }
        assert_eq!(said, vec![(1.0, 1.0)]);
    }

    #[test]
    fn no_timeout_keeps_every_camera() {
        let mut r = Roster::new(vec!["a".into(), "b".into()], vec![0], None);
        r.track(0, 0);
        assert!(r.track(0, 3_600_000 * MS).is_empty());
        assert!(r.publishing());
    }
}
