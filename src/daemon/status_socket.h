// A read-only status socket: whoever connects gets one JSON document, then the connection
// closes. The daemon never reads from it, so it takes no commands. The socket file is made
// 0660 (owner and group only), and each peer's credentials are checked too (SO_PEERCRED), so
// a socket made world-accessible by mistake still serves only root, the daemon's own user and
// the socket's group. It is never created in a directory others may write without the
// sticky bit (they could swap the file), nor over a file that is not a socket, nor over a
// socket a running process answers on (a second instance with the same status_socket); the
// file it leaves at exit is removed only if it is still the one it made.
#pragma once

#include <sys/types.h>

#include <functional>
#include <optional>
#include <string>

#include "core/event_loop.h"
#include "core/result.h"
#include "core/unique_fd.h"

namespace mavbond {

class StatusSocket {
public:
    using Producer = std::function<std::string()>;
    static Result<std::unique_ptr<StatusSocket>> open(const std::string& path, EventLoop& loop,
                                                      Producer producer);
    /// The process that answers on the socket at `path` now (its pid), if one does: a file
    /// left by a crash answers no one.
    static std::optional<pid_t> answered_by(const std::string& path);
    /// Why a daemon may not take `path`: answered by `pid`.
    static std::string in_use_message(const std::string& path, pid_t pid);
    ~StatusSocket();
    /// Connections refused by the credentials check.
    uint64_t refused() const { return refused_; }

private:
    StatusSocket(std::string path, UniqueFd fd, Producer producer, dev_t dev, ino_t ino)
        : path_(std::move(path)), fd_(std::move(fd)), producer_(std::move(producer)),
          dev_(dev), ino_(ino) {}
    void on_accept();
    bool peer_allowed(int client_fd);

    std::string path_;
    UniqueFd fd_;
    Producer producer_;
    EventLoop::Watch watch_;
    uint64_t refused_ = 0;
    dev_t dev_;  // the file bind() made: removed at exit only while it is still there
    ino_t ino_;
};

}  // namespace mavbond
