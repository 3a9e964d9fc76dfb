//! Peak memory of a phase of a benchmark, from `/proc/self/status` (Linux; elsewhere nothing is
//! reported). Shared by the scale benchmarks through `#[path]`.

/// A field of `/proc/self/status` in kB (`VmRSS:`, `VmHWM:`).
pub fn status_kb(key: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(key))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Peak-RSS probe of one phase: `VmHWM` reset at its start by writing `5` to
/// `/proc/self/clear_refs` (or, where that is refused, compared with the never-reset peak).
pub struct Peak {
    /// Whether `clear_refs` reset the peak; otherwise `hwm0` is the old, never-reset peak.
    reset: bool,
    rss0: u64,
    hwm0: u64,
}

impl Peak {
    pub fn start() -> Peak {
        let reset = std::fs::write("/proc/self/clear_refs", "5").is_ok();
        let rss0 = status_kb("VmRSS:").unwrap_or(0);
        let hwm0 = status_kb("VmHWM:").unwrap_or(0);
        Peak { reset, rss0, hwm0 }
    }

    /// The resident memory at `start`, in bytes.
    pub fn before(&self) -> u64 {
        self.rss0 * 1024
    }

    /// Peak increase over the RSS at `start`, in bytes (`None` when it cannot be told: no reset
    /// and the phase did not set a new process peak).
    pub fn increase(&self) -> Option<u64> {
        let hwm = status_kb("VmHWM:")?;
        (self.reset || hwm > self.hwm0).then(|| hwm.saturating_sub(self.rss0) * 1024)
    }
}
