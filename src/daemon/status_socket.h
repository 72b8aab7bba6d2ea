// A read-only status socket: whoever connects gets one JSON document, then the connection
// closes. The daemon never reads from it, so it takes no commands. The socket file is made
// 0660 (owner and group only), and each peer's credentials are checked too (SO_PEERCRED), so
// a socket made world-accessible by mistake still serves only root, the daemon's own user and
// the socket's group. It is never created in a directory others may write without the
// sticky bit (they could swap the file), nor over a file that is not a socket.
#pragma once

#include <functional>
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
    ~StatusSocket();
    /// Connections refused by the credentials check.
    uint64_t refused() const { return refused_; }

private:
    StatusSocket(std::string path, UniqueFd fd, Producer producer)
        : path_(std::move(path)), fd_(std::move(fd)), producer_(std::move(producer)) {}
    void on_accept();
    bool peer_allowed(int client_fd);

    std::string path_;
    UniqueFd fd_;
    Producer producer_;
    EventLoop::Watch watch_;
    uint64_t refused_ = 0;
};

}  // namespace mavbond
