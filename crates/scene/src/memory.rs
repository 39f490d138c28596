//! What memory this process may still allocate: /proc/meminfo's `MemAvailable`, the cgroup
//! memory limits (v1 and v2) and the address-space limit, the least of them.

/// Memory this process may still allocate, where the platform says, and what limits it: the
/// least of the machine's free memory (Linux: `MemAvailable`), what its cgroup's memory limit
/// leaves (v2 `memory.max` − `memory.current` of its cgroup and every ancestor, or v1
/// `memory.limit_in_bytes` − `memory.usage_in_bytes`), and what its address-space limit
/// (`RLIMIT_AS`, `ulimit -v`) leaves above its current size. A scene is refused against it
/// before anything is allocated, rather than aborting on a failed allocation (a container's
/// OOM kill, or a `ulimit -v` abort).
pub fn available_memory() -> Option<(u64, &'static str)> {
    let read = |path: &str| std::fs::read_to_string(path).ok();
    let machine = read("/proc/meminfo")
        .and_then(|t| kib_field(&t, "MemAvailable:"))
        .map(|b| (b, "available on this machine"));
    let cgroup = read("/proc/self/cgroup")
        .and_then(|t| cgroup_room(&t, &|p| read(p)))
        .map(|b| (b, "left by this process's cgroup memory limit"));
    let address_space = read("/proc/self/limits")
        .and_then(|t| address_space_limit(&t))
        .zip(read("/proc/self/status").and_then(|t| kib_field(&t, "VmSize:")))
        .map(|(limit, size)| {
            (
                limit.saturating_sub(size),
                "left by this process's address-space limit (ulimit -v)",
            )
        });
    [machine, cgroup, address_space]
        .into_iter()
        .flatten()
        .min_by_key(|&(bytes, _)| bytes)
}

/// Bytes of a `Name:   N kB` line of /proc/meminfo or /proc/self/status.
fn kib_field(text: &str, name: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.starts_with(name))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// The soft limit of `Max address space` in /proc/self/limits, bytes (`None`: unlimited).
fn address_space_limit(limits: &str) -> Option<u64> {
    let line = limits
        .lines()
        .find(|l| l.starts_with("Max address space"))?;
    line["Max address space".len()..]
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// What the memory limits of the cgroups in /proc/self/cgroup (`cgroups`) leave, bytes: the
/// least over the process's cgroup and its ancestors of limit − usage, read through `read`
/// (v2: `0::/path`, files under /sys/fs/cgroup/path; v1: the `memory` controller's line, files
/// under /sys/fs/cgroup/memory/path). `None` where no limit is set.
fn cgroup_room(cgroups: &str, read: &dyn Fn(&str) -> Option<String>) -> Option<u64> {
    let number = |text: Option<String>| text?.trim().parse::<u64>().ok();
    let mut room: Option<u64> = None;
    for line in cgroups.lines() {
        let mut fields = line.splitn(3, ':');
        let (_, controllers, path) = (fields.next()?, fields.next()?, fields.next()?);
        let (root, limit_file, usage_file) = if controllers.is_empty() {
            ("/sys/fs/cgroup", "memory.max", "memory.current")
        } else if controllers.split(',').any(|c| c == "memory") {
            (
                "/sys/fs/cgroup/memory",
                "memory.limit_in_bytes",
                "memory.usage_in_bytes",
            )
        } else {
            continue;
        };
        // The cgroup and each ancestor up to the root ("" below): a limit may be set on any.
        let mut dirs = Vec::new();
        let mut dir = path.trim_end_matches('/');
        loop {
            dirs.push(dir);
            match dir.rfind('/') {
                Some(cut) => dir = &dir[..cut],
                None => break,
            }
        }
        for dir in dirs {
            let at = |file: &str| format!("{root}{dir}/{file}");
            // "max" (v2) does not parse: no limit; v1 says "none" with a huge number.
            if let (Some(limit), Some(usage)) =
                (number(read(&at(limit_file))), number(read(&at(usage_file))))
                && limit < u64::MAX / 2
            {
                let left = limit.saturating_sub(usage);
                room = Some(room.map_or(left, |r| r.min(left)));
            }
        }
    }
    room
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_limits_are_read_from_proc_and_the_cgroup_files() {
        let status = "Name:\tsoftbody\nVmPeak:\t  9000 kB\nVmSize:\t  8192 kB\n";
        assert_eq!(kib_field(status, "VmSize:"), Some(8192 * 1024));
        let limits = "Limit                     Soft Limit           Hard Limit           Units\n\
                      Max stack size            8388608              unlimited            bytes\n\
                      Max address space         1073741824           unlimited            bytes\n";
        assert_eq!(address_space_limit(limits), Some(1 << 30));
        let unlimited = limits.replace("1073741824", "unlimited ");
        assert_eq!(address_space_limit(&unlimited), None);

        // v2: a limit on the parent of the process's cgroup counts.
        let files = |path: &str| -> Option<String> {
            match path {
                "/sys/fs/cgroup/user/job/memory.max" => Some("max\n".into()),
                "/sys/fs/cgroup/user/job/memory.current" => Some("100\n".into()),
                "/sys/fs/cgroup/user/memory.max" => Some("5000\n".into()),
                "/sys/fs/cgroup/user/memory.current" => Some("1000\n".into()),
                "/sys/fs/cgroup/memory.max" => None,
                // v1, memory controller.
                "/sys/fs/cgroup/memory/box/memory.limit_in_bytes" => Some("3000\n".into()),
                "/sys/fs/cgroup/memory/box/memory.usage_in_bytes" => Some("500\n".into()),
                "/sys/fs/cgroup/memory/memory.limit_in_bytes" => {
                    Some("9223372036854771712\n".into())
                }
                "/sys/fs/cgroup/memory/memory.usage_in_bytes" => Some("9000\n".into()),
                _ => None,
            }
        };
        assert_eq!(cgroup_room("0::/user/job\n", &files), Some(4000));
        assert_eq!(
            cgroup_room("4:memory:/box\n3:cpu:/other\n", &files),
            Some(2500)
        );
        assert_eq!(cgroup_room("0::/\n", &files), None, "no limit anywhere");
        assert_eq!(cgroup_room("garbage", &files), None);
    }
}
