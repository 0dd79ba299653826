//! Per-topic rate limits of the live bridge on a caller-supplied clock (nanoseconds); a viz file
//! uses unlimited ones (`Throttle::new(0.0)`).

/// Lets through at most `hz` events per second; `hz <= 0` lets everything through.
#[derive(Debug, Clone)]
pub struct Throttle {
    interval_ns: u64,
    last_ns: Option<u64>,
    /// Events that were due but not let through.
    pub skipped: u64,
}

impl Throttle {
    pub fn new(hz: f64) -> Throttle {
        let interval_ns = if hz > 0.0 && hz.is_finite() { (1e9 / hz) as u64 } else { 0 };
        Throttle { interval_ns, last_ns: None, skipped: 0 }
    }

    /// True when an event at `now_ns` may pass (without taking the slot: see [`Throttle::take`]).
    pub fn due(&self, now_ns: u64) -> bool {
        match self.last_ns {
            None => true,
            // A clock that goes back (a new recording file) lets the event through.
            Some(last) => now_ns < last || now_ns - last >= self.interval_ns,
        }
    }

    /// Marks an event as sent at `now_ns`.
    pub fn take(&mut self, now_ns: u64) {
        self.last_ns = Some(now_ns);
    }

    /// [`Throttle::due`] and, if so, [`Throttle::take`]; counts what it holds back.
    pub fn admit(&mut self, now_ns: u64) -> bool {
        if self.due(now_ns) {
            self.take(now_ns);
            true
        } else {
            self.skipped += 1;
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thirty_hz_lets_through_one_event_per_33_ms() {
        let mut t = Throttle::new(30.0);
        let ms = 1_000_000;
        let passed = (0..1000u64).filter(|i| t.admit(i * ms)).count();
        assert_eq!(passed, 30, "0, 34, 68, ..., 986 ms within one second");
        assert_eq!(t.skipped, 1000 - 30);
    }

    #[test]
    fn zero_hz_is_unlimited() {
        let mut t = Throttle::new(0.0);
        assert!((0..10).all(|_| t.admit(5)));
    }
}
