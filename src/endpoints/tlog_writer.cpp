#include "endpoints/tlog_writer.h"

#include <fcntl.h>
#include <pthread.h>
#include <signal.h>
#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>

#include "core/log.h"
#include "core/plural.h"
#include "endpoints/net.h"
#include "mavlink/frame.h"

namespace mavbond {
namespace {

constexpr uint32_t kSystemTimeId = 2;        // SYSTEM_TIME: time_unix_usec u64, time_boot_ms u32
constexpr size_t kTimeBootOffset = 8;
constexpr uint8_t kAutopilotCompid = 1;      // MAV_COMP_ID_AUTOPILOT1
// time_boot_ms going back by more than this is a reboot; less is reordering between links.
constexpr int64_t kRebootSlackMs = 5000;

std::string utc_stamp() {
    time_t t = time(nullptr);
    tm parts{};
    gmtime_r(&t, &parts);
    char buf[32];
    strftime(buf, sizeof buf, "%Y-%m-%d_%H-%M-%S", &parts);
    return buf;
}

}  // namespace

TlogWriter::TlogWriter(std::string log_name, std::string directory, uint64_t max_size,
                       size_t ring_bytes)
    : name_(std::move(log_name)), directory_(std::move(directory)), max_size_(max_size),
      ring_(ring_bytes), last_boot_ms_(256, -1) {
    out_.reserve(kWriteChunk + RecordRing::kMaxRecord);
    record_.resize(RecordRing::kMaxRecord);
    open_next_file();
    // Signals are the loop's (signalfd): the thread starts with all of them blocked, or one
    // not blocked yet (SIGUSR1) would be delivered to it and kill the daemon. SIGXFSZ too: a
    // file size limit is then a write error (EFBIG), handled like a full disk.
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_BLOCK, &all, &old);
    thread_ = std::jthread([this](std::stop_token stop) { run(stop); });
    pthread_sigmask(SIG_SETMASK, &old, nullptr);
}

TlogWriter::~TlogWriter() {
    thread_.request_stop();
    if (thread_.joinable())
        thread_.join();
}

TlogWriter::Counters TlogWriter::counters() const {
    return Counters{frames_lost_.load(), bytes_lost_.load(), write_errors_.load()};
}

void TlogWriter::run(std::stop_token stop) {
    std::unique_lock lock(mutex_);
    while (!stop.stop_requested()) {
        cv_.wait_for(lock, stop, kDrainPeriod, [this] { return wake_.load(); });
        wake_.store(false);
        lock.unlock();
        drain();
        lock.lock();
    }
    lock.unlock();
    // The loop pushes nothing any more: what is left is the last of the log.
    drain();
    close_file();
}

void TlogWriter::drain() {
    while (size_t n = ring_.pop(record_.data())) {
        std::span<const uint8_t> record(record_.data(), n);
        if (fd_) {
            if (const char* why = rotation_reason(record)) {
                close_file();
                log_info("[tlog:%s] %s: starting a new file", name_.c_str(), why);
                open_next_file();
            }
        }
        if (!fd_ && Clock::now() >= next_open_try_)
            open_next_file();
        out_.insert(out_.end(), record.begin(), record.end());
        out_frames_++;
        out_frame_bytes_ += n - kTimestampBytes;
        file_bytes_ += n;
        if (out_.size() >= kWriteChunk)
            write_out();
    }
    write_out();
    check_file_still_there();
}

const char* TlogWriter::rotation_reason(std::span<const uint8_t> record) {
    bool rebooted = autopilot_rebooted(record.subspan(kTimestampBytes));
    if (file_frames_ + out_frames_ == 0)
        return nullptr;
    if (max_size_ != 0 && file_bytes_ + record.size() > max_size_)
        return "size limit reached";
    return rebooted ? "autopilot rebooted" : nullptr;
}

bool TlogWriter::autopilot_rebooted(std::span<const uint8_t> frame) {
    bool v2 = !frame.empty() && frame[0] == kMagicV2;
    size_t header = v2 ? kHeaderLenV2 : kHeaderLenV1;
    if (frame.size() < header + kChecksumLen)
        return false;
    uint32_t msgid = v2 ? frame[7] | (frame[8] << 8) | (frame[9] << 16) : frame[5];
    uint8_t sysid = frame[v2 ? 5 : 3];
    uint8_t compid = frame[v2 ? 6 : 4];
    if (msgid != kSystemTimeId || compid != kAutopilotCompid)
        return false;
    // A v2 payload may be cut short of its trailing zeros: read it zero-extended.
    uint8_t payload[12] = {};
    std::memcpy(payload, frame.data() + header, 
                std::min<size_t>({frame[1], sizeof payload, frame.size() - header}));
    uint32_t boot_ms;
    std::memcpy(&boot_ms, payload + kTimeBootOffset, sizeof boot_ms);  // little-endian host
    int64_t& last = last_boot_ms_[sysid];
    bool rebooted = last >= 0 && int64_t{boot_ms} + kRebootSlackMs < last;
    last = boot_ms;
    return rebooted;
}

bool TlogWriter::open_next_file() {
    // Created until it exists once: one that vanishes later (a card unmounted) is an error,
    // so the log never lands on whatever filesystem is underneath.
    if (!directory_made_) {
        std::error_code ec;
        std::filesystem::create_directories(directory_, ec);
        if (ec) {
            write_errors_++;
            set_failing("cannot create directory " + directory_ + ": " + ec.message());
            next_open_try_ = Clock::now() + kRetryPeriod;
            return false;
        }
        directory_made_ = true;
    }
    std::string stamp = utc_stamp();
    for (int i = 0; i < 1000; i++) {
        char suffix[16] = "";
        if (i > 0)
            snprintf(suffix, sizeof suffix, "_%03d", i);
        std::string path = directory_ + "/" + stamp + suffix + ".tlog";
        UniqueFd fd(::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_APPEND | O_CLOEXEC, 0644));
        if (fd) {
            fd_ = std::move(fd);
            path_ = path;
            file_bytes_ = out_.size();
            file_frames_ = 0;
            if (failing_)
                set_writing();
            else
                log_info("[tlog:%s] writing %s", name_.c_str(), path_.c_str());
            return true;
        }
        if (errno != EEXIST) {
            write_errors_++;
            set_failing("cannot create " + path + ": " + errno_text(errno));
            next_open_try_ = Clock::now() + kRetryPeriod;
            return false;
        }
    }
    write_errors_++;
    set_failing("no free file name for " + stamp + " in " + directory_);
    next_open_try_ = Clock::now() + kRetryPeriod;
    return false;
}

void TlogWriter::close_file() {
    write_out();
    if (!fd_)
        return;
    if (fsync(fd_.get()) < 0 && errno != EINVAL)
        log_warning("[tlog:%s] fsync %s: %s", name_.c_str(), path_.c_str(), errno_text(errno).c_str());
    fd_.reset();
    log_info("[tlog:%s] closed %s (%s, %s)", name_.c_str(), path_.c_str(),
             plural(file_frames_, "frame").c_str(), plural(file_bytes_, "byte").c_str());
    file_bytes_ = 0;
    file_frames_ = 0;
}

void TlogWriter::write_out() {
    if (out_.empty())
        return;
    if (!fd_) {
        lose_pending();
        return;
    }
    const uint8_t* p = out_.data();
    size_t left = out_.size();
    int err = 0;
    while (left > 0) {
        ssize_t n = ::write(fd_.get(), p, left);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0) {
            err = n < 0 ? errno : ENOSPC;
            break;
        }
        p += n;
        left -= static_cast<size_t>(n);
    }
    if (err == 0) {
        file_frames_ += out_frames_;
        out_.clear();
        out_frames_ = out_frame_bytes_ = 0;
        set_writing();
        return;
    }
    write_errors_++;
    set_failing("cannot write " + path_ + ": " + errno_text(err));
    // The whole records that reached the disk stay (a nearly full disk takes some); a cut one
    // is taken back, so the file stays a sequence of whole records; the rest is lost, counted.
    const size_t written = out_.size() - left;
    size_t kept = 0;
    while (kept + kTimestampBytes + 3 <= written) {
        const size_t frame_len = frame_length(out_.data() + kept + kTimestampBytes);
        if (kept + kTimestampBytes + frame_len > written)
            break;
        kept += kTimestampBytes + frame_len;
        file_frames_++;
        out_frames_--;
        out_frame_bytes_ -= frame_len;
    }
    const uint64_t committed = file_bytes_ - out_.size() + kept;
    if (written == kept || ftruncate(fd_.get(), static_cast<off_t>(committed)) == 0)
        file_bytes_ = committed;
    else
        file_bytes_ = committed + (written - kept);
    lose_pending();
}

void TlogWriter::lose_pending() {
    frames_lost_ += out_frames_;
    bytes_lost_ += out_frame_bytes_;
    if (!fd_)
        file_bytes_ = 0;
    out_.clear();
    out_frames_ = out_frame_bytes_ = 0;
}

void TlogWriter::check_file_still_there() {
    TimePoint now = Clock::now();
    if (!fd_ || now < next_check_)
        return;
    next_check_ = now + kCheckPeriod;
    struct stat st {};
    if (fstat(fd_.get(), &st) == 0 && st.st_nlink == 0) {
        // Deleted, or its directory removed: writes would succeed into nothing.
        write_errors_++;
        set_failing(path_ + " was removed");
        fd_.reset();
        file_bytes_ = file_frames_ = 0;
        next_open_try_ = now;
    }
}

void TlogWriter::set_failing(const std::string& why) {
    if (failing_)
        return;  // once per change of state, not once per retry
    failing_ = true;
    log_error("[tlog:%s] %s; frames are dropped (counted as tx_dropped) until it can write "
              "again, retrying every %llds", name_.c_str(), why.c_str(),
              static_cast<long long>(std::chrono::duration_cast<seconds>(kRetryPeriod).count()));
}

void TlogWriter::set_writing() {
    if (!failing_)
        return;
    failing_ = false;
    log_notice("[tlog:%s] writing again, to %s", name_.c_str(), path_.c_str());
}

}  // namespace mavbond
