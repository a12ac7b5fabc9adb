//! `bag --view`'s pace: the bag's messages at the recording's rate (or a multiple of it), or as
//! fast as they go.

use std::str::FromStr;
use std::time::{Duration, Instant};

/// `--view-rate`: a multiple of the recording's rate, or as fast as it goes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ViewRate {
    /// Log time runs this many times as fast as the wall clock (1 = as recorded).
    Recorded(f64),
    /// No waiting.
    Max,
}

impl FromStr for ViewRate {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.eq_ignore_ascii_case("max") {
            return Ok(Self::Max);
        }
        match s.parse::<f64>() {
            Ok(rate) if rate.is_finite() && rate > 0.0 => Ok(Self::Recorded(rate)),
            _ => Err(format!(
                "`{s}`: a rate is a positive multiple of the recording's (1 = as recorded) or `max`"
            )),
        }
    }
}

/// Holds each message back until its log time, relative to the first message, has come on the
/// wall clock (scaled by the rate). A processing slower than the recording never waits.
#[derive(Debug)]
pub struct Pacer {
    rate: f64,
    start: Option<(Instant, u64)>,
}

impl Pacer {
    /// `None` for [`ViewRate::Max`].
    pub fn new(rate: ViewRate) -> Option<Self> {
        match rate {
            ViewRate::Recorded(rate) => Some(Self { rate, start: None }),
            ViewRate::Max => None,
        }
    }

    /// How long to wait before the message at `log_time_ns`, measured `now`.
    pub fn delay(&mut self, log_time_ns: u64, now: Instant) -> Duration {
        let (start, first_ns) = *self.start.get_or_insert((now, log_time_ns));
        let since_first = Duration::from_nanos(log_time_ns.saturating_sub(first_ns));
        let due = start + since_first.div_f64(self.rate);
        due.saturating_duration_since(now)
    }

    /// Sleeps until the message at `log_time_ns` is due.
    pub fn wait(&mut self, log_time_ns: u64) {
        let delay = self.delay(log_time_ns, Instant::now());
        if !delay.is_zero() {
            std::thread::sleep(delay);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_parse() {
        assert_eq!("max".parse::<ViewRate>(), Ok(ViewRate::Max));
        assert_eq!("2".parse::<ViewRate>(), Ok(ViewRate::Recorded(2.0)));
        assert!("0".parse::<ViewRate>().is_err());
        assert!("-1".parse::<ViewRate>().is_err());
        assert!("fast".parse::<ViewRate>().is_err());
    }

    #[test]
    fn messages_are_due_at_their_scaled_log_time() {
        let mut pacer = Pacer::new(ViewRate::Recorded(2.0)).unwrap();
        let t0 = Instant::now();
        assert_eq!(pacer.delay(10_000_000_000, t0), Duration::ZERO);
        // One recorded second later, at twice the rate: due half a second after the first.
        assert_eq!(pacer.delay(11_000_000_000, t0), Duration::from_millis(500));
        // Processing fell behind: no wait.
        assert_eq!(
            pacer.delay(11_000_000_000, t0 + Duration::from_secs(3)),
            Duration::ZERO
        );
        assert!(Pacer::new(ViewRate::Max).is_none());
    }
}
