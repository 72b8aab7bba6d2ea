#include "core/status_socket.h"

#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>

#include <cerrno>
#include <cstring>

#include "core/log.h"

namespace mavbond {

Result<std::unique_ptr<StatusSocket>> StatusSocket::open(const std::string& path, EventLoop& loop,
                                                         Producer producer) {
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    if (path.size() >= sizeof addr.sun_path)
        return make_error("status socket path too long: " + path);
    std::memcpy(addr.sun_path, path.c_str(), path.size() + 1);
    UniqueFd fd(socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0));
    if (!fd)
        return make_error(std::string("socket: ") + strerror(errno));
    // A socket left by a previous run (a crash, a kill -9) is replaced; any other file is not.
    struct stat st {};
    if (lstat(path.c_str(), &st) == 0) {
        if (!S_ISSOCK(st.st_mode))
            return make_error("status socket " + path + " exists and is not a socket");
        unlink(path.c_str());
    }
    mode_t old = umask(0117);  // 0660
    int rc = bind(fd.get(), reinterpret_cast<const sockaddr*>(&addr), sizeof addr);
    umask(old);
    if (rc < 0)
        return make_error("cannot bind status socket " + path + ": " + strerror(errno));
    if (listen(fd.get(), 8) < 0)
        return make_error("cannot listen on status socket " + path + ": " + strerror(errno));
    std::unique_ptr<StatusSocket> s(new StatusSocket(path, std::move(fd), std::move(producer)));
    auto w = loop.watch(s->fd_.get(), EPOLLIN, [p = s.get()](uint32_t) { p->on_accept(); });
    if (!w)
        return w.error();
    s->watch_ = std::move(w.value());
    log_info("status socket at %s", path.c_str());
    return s;
}

StatusSocket::~StatusSocket() {
    watch_.reset();
    unlink(path_.c_str());
}

void StatusSocket::on_accept() {
    for (;;) {
        UniqueFd client(accept4(fd_.get(), nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC));
        if (!client)
            return;
        std::string doc = producer_() + "\n";
        // The document is a few KiB: it fits the socket buffer, so one non-blocking send does;
        // a reader that is not reading gets a cut document, never a stalled daemon.
        ssize_t n = send(client.get(), doc.data(), doc.size(), MSG_DONTWAIT | MSG_NOSIGNAL);
        if (n != static_cast<ssize_t>(doc.size()))
            log_debug("status socket: sent %zd of %zu bytes", n, doc.size());
    }
}

}  // namespace mavbond
