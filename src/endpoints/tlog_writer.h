// The disk side of a flight log: a thread that drains a ring of timestamped frames into .tlog
// files with large writes, so the event loop only ever copies into memory.
//
// Files are named from the wall clock in UTC (2026-11-21_14-03-07.tlog; _001, _002, ... when
// the name is taken: a file is never overwritten, and names sort in time order). A new file is
// started at each daemon start, when the current one would pass max_size, and when the
// autopilot reboots (its SYSTEM_TIME.time_boot_ms goes back). Disk errors (ENOSPC, EIO, the
// directory gone) cost the frames they hit, counted; each change between writing and failing
// is logged once; the writer retries and routing goes on.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "core/clock.h"
#include "core/unique_fd.h"
#include "endpoints/record_ring.h"

namespace mavbond {

class TlogWriter {
public:
    static constexpr size_t kTimestampBytes = 8;

    struct Counters {
        uint64_t frames_lost = 0;   // popped from the ring but never on disk (errors, no file)
        uint64_t bytes_lost = 0;    // their frame bytes
        uint64_t write_errors = 0;  // failed writes and failed file creations
    };

    /// Creates `directory` (and its parents) if missing, opens the first file now (a failure
    /// is logged and retried), and starts the thread. `log_name` prefixes the log lines.
    TlogWriter(std::string log_name, std::string directory, uint64_t max_size,
               size_t ring_bytes);
    /// Drains everything queued, fsyncs, closes the file and joins the thread.
    ~TlogWriter();
    TlogWriter(const TlogWriter&) = delete;
    TlogWriter& operator=(const TlogWriter&) = delete;

    /// Loop thread: queues one record (the big-endian timestamp, then the frame); false when
    /// the ring is full.
    bool push(std::span<const uint8_t, kTimestampBytes> stamp, std::span<const uint8_t> frame) {
        return ring_.push(stamp, frame);
    }
    /// Loop thread, after a batch of pushes: wakes the writer early when the ring fills up
    /// (otherwise it drains every kDrainPeriod on its own).
    void pushed() {
        if (ring_.used() >= ring_.capacity() / 4 && !wake_.exchange(true))
            cv_.notify_one();
    }
    /// Asks for a drain now.
    void wake() {
        wake_.store(true);
        cv_.notify_one();
    }
    Counters counters() const;

private:
    static constexpr Duration kDrainPeriod = milliseconds(100);
    static constexpr Duration kRetryPeriod = seconds(5);
    static constexpr Duration kCheckPeriod = seconds(1);
    static constexpr size_t kWriteChunk = 256 * 1024;

    void run(std::stop_token stop);
    void drain();
    /// Whether `record` must start a new file: the size limit, or the autopilot rebooted.
    const char* rotation_reason(std::span<const uint8_t> record);
    bool autopilot_rebooted(std::span<const uint8_t> frame);
    bool open_next_file();
    void close_file();
    void write_out();
    void lose_pending();
    void check_file_still_there();
    void set_failing(const std::string& why);
    void set_writing();

    std::string name_;
    std::string directory_;
    uint64_t max_size_;
    RecordRing ring_;
    std::atomic<bool> wake_{false};
    std::mutex mutex_;  // only for cv_
    std::condition_variable_any cv_;

    // Writer thread only, after construction.
    UniqueFd fd_;
    std::string path_;
    uint64_t file_bytes_ = 0;   // on disk and in out_
    uint64_t file_frames_ = 0;
    std::vector<uint8_t> out_;  // records waiting for one large write
    uint64_t out_frames_ = 0;
    uint64_t out_frame_bytes_ = 0;
    std::vector<uint8_t> record_;
    std::vector<int64_t> last_boot_ms_;  // per sysid; -1: no SYSTEM_TIME seen yet
    bool failing_ = false;
    bool directory_made_ = false;
    TimePoint next_open_try_{};
    TimePoint next_check_{};

    std::atomic<uint64_t> frames_lost_{0};
    std::atomic<uint64_t> bytes_lost_{0};
    std::atomic<uint64_t> write_errors_{0};

    std::jthread thread_;  // last: it starts after everything above exists
};

}  // namespace mavbond
