//! What the operating system can do for a real-time thread: a monotonic clock, absolute
//! sleeps, SCHED_FIFO, locked memory, a pinned CPU. Each request may be refused (no
//! privileges, a container); the loop then runs without it and says so.

#![allow(unsafe_code)]

use bdft_protocol::controller_to_server::RealtimeStatus;

/// Nanoseconds on CLOCK_MONOTONIC (the clock absolute sleeps are measured against).
#[inline]
pub fn now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: ts is a valid out-pointer; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Sleeps until the absolute CLOCK_MONOTONIC time `deadline_ns` (no drift: the deadline, not
/// the duration, is what is asked for). Interrupted sleeps are resumed.
#[inline]
pub fn sleep_until(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: ts is a valid timespec; a null remainder is allowed with TIMER_ABSTIME.
        let r = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if r != libc::EINTR {
            return;
        }
    }
}

/// Asks for real-time treatment of the calling thread; returns what was granted and a line
/// for the log per refusal.
pub fn make_realtime(priority: i32, cpu: Option<usize>) -> (RealtimeStatus, Vec<String>) {
    let mut status = RealtimeStatus::default();
    let mut refused = Vec::new();
    // SAFETY: plain syscalls on the current thread with valid arguments.
    unsafe {
        let param = libc::sched_param {
            sched_priority: priority,
        };
        let r = libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param);
        if r == 0 {
            status.sched_fifo = true;
        } else {
            refused.push(format!(
                "SCHED_FIFO priority {priority} refused ({}); running at normal priority",
                std::io::Error::from_raw_os_error(r)
            ));
            // Without FIFO, at least ask for precise timers (default slack is 50 µs).
            libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0);
        }
        if libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) == 0 {
            status.memory_locked = true;
        } else {
            refused.push(format!(
                "mlockall refused ({}); memory may be paged",
                std::io::Error::last_os_error()
            ));
        }
        if let Some(cpu) = cpu {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_SET(cpu, &mut set);
            let r = libc::pthread_setaffinity_np(
                libc::pthread_self(),
                std::mem::size_of::<libc::cpu_set_t>(),
                &set,
            );
            if r == 0 {
                status.pinned_cpu = Some(cpu);
            } else {
                refused.push(format!(
                    "pinning to CPU {cpu} refused ({})",
                    std::io::Error::from_raw_os_error(r)
                ));
            }
        }
    }
    (status, refused)
}

/// Minor page faults the calling thread has taken so far.
#[cfg(test)]
pub fn minor_faults() -> u64 {
    // SAFETY: getrusage fills the struct it is given; zeroed is a valid rusage.
    unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_THREAD, &mut usage);
        usage.ru_minflt as u64
    }
}

/// Number of CPUs this process may run on.
pub fn cpu_count() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}
