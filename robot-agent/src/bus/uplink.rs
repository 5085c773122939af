//! What goes up a slow link first: the robot's uplink budget.
//!
//! On Wi-Fi at the edge of range or on LTE the robot produces more map than the link carries. An
//! unlimited queue then delays everything behind the tiles, poses included, and the operator
//! watches a robot that stands still on the screen while it drives. This scheduler decides the
//! order and the pace instead:
//!
//! - **Small messages first.** Pose, status, path, session and route go out at once, in the order
//!   they came; they are what an operator needs every second.
//! - **Tiles coalesced.** A tile waiting to be sent that changes again is replaced by its newer
//!   version: the link never carries a version nobody needs any more.
//! - **Newest-changed first,** so the map where the robot is now arrives first; a tile that has
//!   waited `max_wait_s` goes ahead of newer ones (oldest first), so a link that keeps up on
//!   average starves nothing.
//! - **Budget.** A token bucket of `budget_kbps` (kilobits per second, 0 = unlimited) with a burst
//!   of [`BURST_S`] seconds. Small messages are never held (they may overdraw the bucket; tiles
//!   then wait until it has refilled), so poses keep their rate even when the budget is smaller
//!   than the tiles need.
//!
//! What is counted is what the application hands to Zenoh: key and payload, plus
//! [`MESSAGE_OVERHEAD_BYTES`] per message for Zenoh's framing and the transport headers it shares
//! between the messages of a batch. Replies to a station's resync query are not counted: they are
//! asked for.
//!
//! Nothing is lost while the link is slow or down: the newest version of every tile stays queued
//! (and is served by the tile queryable from the moment it was produced).
//!
//! Pure: no Zenoh, no clock; the caller passes the time.

use common::grid::TileIndex;
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

/// Seconds of budget the bucket holds when the link has been idle.
pub const BURST_S: f64 = 1.0;

/// Bytes counted per message on top of key and payload.
pub const MESSAGE_OVERHEAD_BYTES: usize = 32;

/// The scheduler's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UplinkPolicy {
    /// Budget in kilobits per second (1 kbit = 1000 bits); 0 = unlimited.
    pub budget_kbps: f64,
    /// A tile waiting this long goes ahead of newer ones, seconds.
    pub max_wait_s: f64,
}

impl Default for UplinkPolicy {
    fn default() -> Self {
        Self {
            budget_kbps: 0.0,
            max_wait_s: 10.0,
        }
    }
}

/// What the scheduler says to do next.
#[derive(Debug, PartialEq)]
pub enum Next<M> {
    /// Send this now.
    Send(M),
    /// Nothing may go before this much time has passed (the bucket refills).
    Wait(Duration),
    /// Nothing is queued.
    Idle,
}

/// Counters, for logs and the benchmark.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UplinkCounters {
    /// Bytes handed out (as counted against the budget).
    pub bytes_sent: u64,
    /// Messages handed out.
    pub messages_sent: u64,
    /// Tile versions replaced by a newer one before they were sent.
    pub tiles_coalesced: u64,
    /// Most tiles queued at once.
    pub max_tiles_queued: usize,
}

struct QueuedTile<M> {
    msg: M,
    bytes: usize,
    /// Order of the latest change (higher = newer).
    changed_seq: u64,
    /// When the tile first queued since it was last sent (overdue is measured from here).
    first_queued_s: f64,
}

/// See the module docs.
pub struct Uplink<M> {
    /// Bytes per second; None = unlimited.
    rate_bps: Option<f64>,
    capacity_b: f64,
    tokens_b: f64,
    last_s: f64,
    max_wait_s: f64,
    control: VecDeque<(M, usize)>,
    tiles: BTreeMap<TileIndex, QueuedTile<M>>,
    /// Tiles by change order: the newest is the last entry.
    by_change: BTreeMap<u64, TileIndex>,
    seq: u64,
    counters: UplinkCounters,
}

impl<M> Uplink<M> {
    /// A scheduler starting at time `now_s` with a full bucket.
    pub fn new(policy: UplinkPolicy, now_s: f64) -> Self {
        let rate_bps = (policy.budget_kbps.is_finite() && policy.budget_kbps > 0.0)
            .then(|| policy.budget_kbps * 1000.0 / 8.0);
        let capacity_b = rate_bps.map_or(0.0, |r| r * BURST_S);
        Self {
            rate_bps,
            capacity_b,
            tokens_b: capacity_b,
            last_s: now_s,
            max_wait_s: policy.max_wait_s,
            control: VecDeque::new(),
            tiles: BTreeMap::new(),
            by_change: BTreeMap::new(),
            seq: 0,
            counters: UplinkCounters::default(),
        }
    }

    /// Bytes a message of `key_len` and `payload_len` counts against the budget.
    pub fn cost(key_len: usize, payload_len: usize) -> usize {
        key_len + payload_len + MESSAGE_OVERHEAD_BYTES
    }

    /// Queues a small message (pose, status, path, session, route) of `bytes`.
    pub fn push_control(&mut self, msg: M, bytes: usize) {
        self.control.push_back((msg, bytes));
    }

    /// Queues tile `index` of `bytes` at `now_s`, replacing a version of it still waiting.
    pub fn push_tile(&mut self, index: TileIndex, msg: M, bytes: usize, now_s: f64) {
        self.seq += 1;
        let changed_seq = self.seq;
        let first_queued_s = match self.tiles.remove(&index) {
            Some(old) => {
                self.by_change.remove(&old.changed_seq);
                self.counters.tiles_coalesced += 1;
                old.first_queued_s
            }
            None => now_s,
        };
        self.tiles.insert(
            index,
            QueuedTile {
                msg,
                bytes,
                changed_seq,
                first_queued_s,
            },
        );
        self.by_change.insert(changed_seq, index);
        self.counters.max_tiles_queued = self.counters.max_tiles_queued.max(self.tiles.len());
    }

    /// Drops every waiting tile (a new session starts a new map).
    pub fn clear_tiles(&mut self) {
        self.tiles.clear();
        self.by_change.clear();
    }

    /// Tiles waiting.
    pub fn tiles_queued(&self) -> usize {
        self.tiles.len()
    }

    /// Counters so far.
    pub fn counters(&self) -> UplinkCounters {
        self.counters
    }

    fn refill(&mut self, now_s: f64) {
        if let Some(r) = self.rate_bps {
            let dt = (now_s - self.last_s).max(0.0);
            self.tokens_b = (self.tokens_b + r * dt).min(self.capacity_b);
        }
        self.last_s = self.last_s.max(now_s);
    }

    fn spend(&mut self, bytes: usize) {
        if self.rate_bps.is_some() {
            self.tokens_b -= bytes as f64;
        }
        self.counters.bytes_sent += bytes as u64;
        self.counters.messages_sent += 1;
    }

    /// The tile to send next: an overdue one (oldest first) if any, else the newest change.
    /// Without a budget, tiles go in the order they changed.
    fn next_tile(&self, now_s: f64) -> Option<TileIndex> {
        if self.rate_bps.is_none() {
            return self.by_change.values().next().copied();
        }
        let overdue = self
            .tiles
            .iter()
            .filter(|(_, t)| now_s - t.first_queued_s >= self.max_wait_s)
            .min_by(|a, b| a.1.first_queued_s.total_cmp(&b.1.first_queued_s))
            .map(|(i, _)| *i);
        overdue.or_else(|| self.by_change.values().next_back().copied())
    }

    /// What to do at `now_s`.
    pub fn next(&mut self, now_s: f64) -> Next<M> {
        self.refill(now_s);
        if let Some((msg, bytes)) = self.control.pop_front() {
            self.spend(bytes);
            return Next::Send(msg);
        }
        let Some(index) = self.next_tile(now_s) else {
            return Next::Idle;
        };
        let bytes = self.tiles[&index].bytes;
        if let Some(r) = self.rate_bps {
            // A tile larger than the bucket goes when the bucket is full.
            let need = (bytes as f64).min(self.capacity_b);
            if self.tokens_b < need {
                let wait_s = (need - self.tokens_b) / r;
                return Next::Wait(Duration::from_secs_f64(wait_s.max(1e-3)));
            }
        }
        let t = self
            .tiles
            .remove(&index)
            .expect("index came from the queue");
        self.by_change.remove(&t.changed_seq);
        self.spend(bytes);
        Next::Send(t.msg)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ti(tx: i32) -> TileIndex {
        TileIndex { tx, ty: 0 }
    }

    #[derive(Debug, PartialEq)]
    enum M {
        Pose(u32),
        Tile(i32, u32),
    }

    fn drain(u: &mut Uplink<M>, now_s: f64) -> Vec<M> {
        let mut out = Vec::new();
        while let Next::Send(m) = u.next(now_s) {
            out.push(m);
        }
        out
    }

    #[test]
    fn unlimited_passes_everything_small_messages_first_tiles_in_change_order() {
        let mut u = Uplink::new(UplinkPolicy::default(), 0.0);
        u.push_tile(ti(1), M::Tile(1, 1), 5_000, 0.0);
        u.push_tile(ti(2), M::Tile(2, 1), 5_000, 0.0);
        u.push_control(M::Pose(0), 80);
        assert_eq!(
            drain(&mut u, 0.0),
            vec![M::Pose(0), M::Tile(1, 1), M::Tile(2, 1)]
        );
        assert_eq!(u.next(0.0), Next::Idle);
    }

    #[test]
    fn a_waiting_tile_is_replaced_by_its_newer_version() {
        let mut u = Uplink::new(
            UplinkPolicy {
                budget_kbps: 8.0, // 1000 B/s
                ..UplinkPolicy::default()
            },
            0.0,
        );
        u.push_tile(ti(1), M::Tile(1, 1), 900, 0.0);
        assert_eq!(
            u.next(0.0),
            Next::Send(M::Tile(1, 1)),
            "the burst allows one"
        );
        u.push_tile(ti(1), M::Tile(1, 2), 900, 0.1);
        u.push_tile(ti(1), M::Tile(1, 3), 900, 0.2);
        assert!(matches!(u.next(0.2), Next::Wait(_)));
        assert_eq!(u.counters().tiles_coalesced, 1);
        assert_eq!(drain(&mut u, 2.0), vec![M::Tile(1, 3)], "only the newest");
    }

    #[test]
    fn newest_change_first_unless_a_tile_is_overdue() {
        let mut u = Uplink::new(
            UplinkPolicy {
                budget_kbps: 8.0,
                max_wait_s: 10.0,
            },
            0.0,
        );
        // Empty the bucket.
        u.push_control(M::Pose(0), 1_000);
        drain(&mut u, 0.0);
        u.push_tile(ti(1), M::Tile(1, 1), 500, 0.0);
        u.push_tile(ti(2), M::Tile(2, 1), 500, 0.1);
        u.push_tile(ti(3), M::Tile(3, 1), 500, 0.2);
        assert_eq!(drain(&mut u, 0.8), vec![M::Tile(3, 1)], "newest first");
        // Tile 1 waits past max_wait_s while newer changes keep coming.
        u.push_tile(ti(4), M::Tile(4, 1), 500, 9.0);
        assert_eq!(drain(&mut u, 10.5), vec![M::Tile(1, 1), M::Tile(2, 1)]);
    }

    #[test]
    fn poses_keep_their_rate_and_the_budget_holds_over_a_minute() {
        // 64 kbit/s, poses at 10 Hz, a new 3 kB tile every 50 ms (480 kbit/s offered): the bytes
        // sent stay within the budget plus one burst, and every pose goes out when it is due.
        let budget_kbps = 64.0;
        let mut u = Uplink::new(
            UplinkPolicy {
                budget_kbps,
                ..UplinkPolicy::default()
            },
            0.0,
        );
        let mut poses = Vec::new();
        let mut tiles = 0;
        let dt = 0.01;
        for k in 0..6_000 {
            let t = f64::from(k) * dt;
            if k % 10 == 0 {
                u.push_control(M::Pose(k / 10), 100);
            }
            if k % 5 == 0 {
                let tx = i32::try_from(k % 40).unwrap();
                u.push_tile(ti(tx), M::Tile(tx, k), 3_000, t);
            }
            loop {
                match u.next(t) {
                    Next::Send(M::Pose(p)) => poses.push((p, t)),
                    Next::Send(M::Tile(..)) => tiles += 1,
                    _ => break,
                }
            }
        }
        // A full bucket at the start, the refill over the minute, and one pose that may overdraw.
        let limit = budget_kbps * 1000.0 / 8.0 * (60.0 + BURST_S) + 100.0;
        let sent = u.counters().bytes_sent as f64;
        assert!(sent <= limit, "{sent} B sent, budget {limit} B");
        assert!(
            sent >= 0.9 * limit,
            "the budget is used: {sent} of {limit} B"
        );
        assert_eq!(poses.len(), 600);
        assert!(poses
            .iter()
            .all(|(p, t)| (t - f64::from(*p) * 0.1).abs() < 1e-9));
        assert!(tiles > 100, "{tiles} tiles");
        assert!(u.counters().tiles_coalesced > 0);
    }

    #[test]
    fn a_tile_larger_than_the_bucket_still_goes_once_the_bucket_is_full() {
        let mut u = Uplink::new(
            UplinkPolicy {
                budget_kbps: 8.0,
                ..UplinkPolicy::default()
            },
            0.0,
        );
        u.push_control(M::Pose(0), 1_000);
        drain(&mut u, 0.0);
        u.push_tile(ti(1), M::Tile(1, 1), 5_000, 0.0);
        match u.next(0.5) {
            Next::Wait(d) => assert!((d.as_secs_f64() - 0.5).abs() < 1e-6, "{d:?}"),
            other => panic!("{other:?}"),
        }
        assert_eq!(u.next(1.0), Next::Send(M::Tile(1, 1)));
    }
}
