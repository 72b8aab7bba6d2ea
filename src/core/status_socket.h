// A read-only status socket: whoever connects gets one JSON document, then the connection
// closes. The daemon never reads from it, so it takes no commands. The socket file is made
// 0660 (owner and group only).
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

private:
    StatusSocket(std::string path, UniqueFd fd, Producer producer)
        : path_(std::move(path)), fd_(std::move(fd)), producer_(std::move(producer)) {}
    void on_accept();

    std::string path_;
    UniqueFd fd_;
    Producer producer_;
    EventLoop::Watch watch_;
};

}  // namespace mavbond
