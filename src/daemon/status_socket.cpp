#include "daemon/status_socket.h"

#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>

#include "core/log.h"
#include "core/unique_fd.h"

namespace mavbond {
namespace {

/// Refuses a directory where others may replace the socket file with their own.
Result<void> check_directory(const std::string& path) {
    auto slash = path.rfind('/');
    std::string dir = slash == std::string::npos ? "." : slash == 0 ? "/" : path.substr(0, slash);
    struct stat st {};
    if (stat(dir.c_str(), &st) < 0)
        return make_error("status socket directory " + dir + ": " + strerror(errno));
    if ((st.st_mode & S_IWOTH) && !(st.st_mode & S_ISVTX)) {
        char mode[8];
        snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(st.st_mode & 07777));
        return make_error("refusing to create status socket " + path + ": others may write " +
                          dir + " (mode " + mode + ") and it has no sticky bit");
    }
    return {};
}

}  // namespace

Result<std::unique_ptr<StatusSocket>> StatusSocket::open(const std::string& path, EventLoop& loop,
                                                         Producer producer) {
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    if (path.size() >= sizeof addr.sun_path)
        return make_error("status socket path too long: " + path);
    std::memcpy(addr.sun_path, path.c_str(), path.size() + 1);
    if (auto dir_ok = check_directory(path); !dir_ok)
        return dir_ok.error();
    UniqueFd fd(socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0));
    if (!fd)
        return make_error(std::string("socket: ") + strerror(errno));
    // A socket left by a previous run (a crash, a kill -9) is replaced; one a running process
    // answers on, or any other file, is not.
    struct stat st {};
    if (lstat(path.c_str(), &st) == 0) {
        if (!S_ISSOCK(st.st_mode))
            return make_error("status socket " + path + " exists and is not a socket");
        if (auto pid = answered_by(path))
            return make_error(in_use_message(path, *pid));
        unlink(path.c_str());
    }
    mode_t old = umask(0117);  // 0660
    int rc = bind(fd.get(), reinterpret_cast<const sockaddr*>(&addr), sizeof addr);
    umask(old);
    if (rc < 0)
        return make_error("cannot bind status socket " + path + ": " + strerror(errno));
    if (listen(fd.get(), 8) < 0)
        return make_error("cannot listen on status socket " + path + ": " + strerror(errno));
    if (lstat(path.c_str(), &st) < 0)
        return make_error("status socket " + path + ": " + strerror(errno));
    std::unique_ptr<StatusSocket> s(
        new StatusSocket(path, std::move(fd), std::move(producer), st.st_dev, st.st_ino));
    auto w = loop.watch(s->fd_.get(), EPOLLIN, [p = s.get()](uint32_t) { p->on_accept(); });
    if (!w)
        return w.error();
    s->watch_ = std::move(w.value());
    log_info("status socket at %s", path.c_str());
    return s;
}

std::optional<pid_t> StatusSocket::answered_by(const std::string& path) {
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    if (path.size() >= sizeof addr.sun_path)
        return std::nullopt;
    std::memcpy(addr.sun_path, path.c_str(), path.size() + 1);
    UniqueFd fd(socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0));
    if (!fd)
        return std::nullopt;
    // Non-blocking: a full backlog (EAGAIN) is a live listener too, and never a wait.
    if (connect(fd.get(), reinterpret_cast<const sockaddr*>(&addr), sizeof addr) < 0 &&
        errno != EAGAIN)
        return std::nullopt;  // ECONNREFUSED: nobody listens; the file is a leftover
    ucred cred{};
    socklen_t len = sizeof cred;
    return getsockopt(fd.get(), SOL_SOCKET, SO_PEERCRED, &cred, &len) == 0 ? cred.pid : 0;
}

std::string StatusSocket::in_use_message(const std::string& path, pid_t pid) {
    return "status socket " + path + ": a running process" +
           (pid > 0 ? " (pid " + std::to_string(pid) + ")" : std::string()) +
           " answers there, another mavbond with the same status_socket: stop it first, or "
           "give this one a status_socket of its own";
}

StatusSocket::~StatusSocket() {
    watch_.reset();
    // Only the file this socket made: another daemon may have replaced it since.
    struct stat st {};
    if (lstat(path_.c_str(), &st) == 0 && st.st_dev == dev_ && st.st_ino == ino_)
        unlink(path_.c_str());
}

void StatusSocket::on_accept() {
    for (;;) {
        UniqueFd client(accept4(fd_.get(), nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC));
        if (!client)
            return;
        if (!peer_allowed(client.get()))
            continue;
        std::string doc = producer_() + "\n";
        // The document is a few KiB: it fits the socket buffer, so one non-blocking send does;
        // a reader that is not reading gets a cut document, never a stalled daemon.
        ssize_t n = send(client.get(), doc.data(), doc.size(), MSG_DONTWAIT | MSG_NOSIGNAL);
        if (n != static_cast<ssize_t>(doc.size()))
            log_debug("status socket: sent %zd of %zu bytes", n, doc.size());
    }
}

bool StatusSocket::peer_allowed(int client_fd) {
    ucred cred{};
    socklen_t len = sizeof cred;
    if (getsockopt(client_fd, SOL_SOCKET, SO_PEERCRED, &cred, &len) < 0) {
        refused_++;
        log_warning("status socket: refusing a peer whose credentials are unknown: %s",
                    strerror(errno));
        return false;
    }
    if (cred.uid == 0 || cred.uid == geteuid())
        return true;
    // The group that may read the socket is the socket file's (an admin may chgrp it).
    struct stat st {};
    if (stat(path_.c_str(), &st) == 0) {
        if (cred.gid == st.st_gid)
            return true;
        std::array<gid_t, 64> groups{};
        socklen_t glen = sizeof groups;
        if (getsockopt(client_fd, SOL_SOCKET, SO_PEERGROUPS, groups.data(), &glen) == 0) {
            for (size_t i = 0; i < glen / sizeof(gid_t); i++) {
                if (groups[i] == st.st_gid)
                    return true;
            }
        }
    }
    refused_++;
    log_warning("status socket: refusing pid %d uid %u gid %u: not root, not mavbond's user, "
                "not in the socket's group", static_cast<int>(cred.pid),
                static_cast<unsigned>(cred.uid), static_cast<unsigned>(cred.gid));
    return false;
}

}  // namespace mavbond
