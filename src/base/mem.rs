//! The process's memory as the kernel counts it, for the report's per-stage figures: the
//! resident set now and its peak so far (`/proc/self/status`: `VmRSS`, `VmHWM`), which include
//! the memory-mapped tile windows a stage has touched. Read-only: nothing here resets the peak,
//! so `wait4`/`/usr/bin/time` still see the whole run's.

/// `(current, peak)` resident set in bytes, if the platform reports them (Linux).
pub fn rss() -> Option<(u64, u64)> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let field = |name: &str| -> Option<u64> {
        let line = status.lines().find(|l| l.starts_with(name))?;
        let kb: u64 = line[name.len()..]
            .trim()
            .trim_end_matches("kB")
            .trim()
            .parse()
            .ok()?;
        Some(kb * 1024)
    };
    Some((field("VmRSS:")?, field("VmHWM:")?))
}

/// The peak resident set so far, MiB (0 where unknown).
pub fn peak_mib() -> f64 {
    rss().map_or(0.0, |(_, p)| p as f64 / (1 << 20) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peak_is_at_least_current_and_grows_with_a_touched_allocation() {
        let Some((now, peak)) = rss() else {
            return; // not Linux
        };
        assert!(peak >= now && now > 0);
        let big = vec![1u8; 64 << 20];
        let (_, after) = rss().unwrap();
        assert!(after >= peak && after >= 64 << 20, "{after}");
        assert_eq!(big.iter().map(|&b| b as u64).sum::<u64>(), 64 << 20);
    }
}
