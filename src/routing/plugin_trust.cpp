#include "routing/plugin_trust.h"

#include <fcntl.h>
#include <pwd.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <climits>
#include <cstring>
#include <deque>
#include <optional>

namespace mavbond {
namespace {

constexpr int kMaxSymlinks = 40;  // as the kernel's path walk (ELOOP)

std::string uid_label(uid_t uid) {
    std::string label = "uid " + std::to_string(uid);
    passwd pw{};
    passwd* found = nullptr;
    std::array<char, 1024> buf{};
    if (getpwuid_r(uid, &pw, buf.data(), buf.size(), &found) == 0 && found)
        label += std::string(" (") + found->pw_name + ")";
    return label;
}

std::string mode_text(mode_t mode) {
    char text[8];
    snprintf(text, sizeof text, "%04o", static_cast<unsigned>(mode & 07777));
    return text;
}

/// The owners whose files the daemon may run: root, its own user, its executable's owner.
class Owners {
public:
    Owners() : self_(geteuid()) {
        struct stat st {};
        exe_ = stat("/proc/self/exe", &st) == 0 ? st.st_uid : 0;
    }
    bool trusted(uid_t uid) const { return uid == 0 || uid == self_ || uid == exe_; }
    /// "owned by uid 65534 (nobody), not by root, ..." for a component that is not.
    std::string refusal(const char* what, const std::string& path, uid_t uid) const {
        std::string others = "root, " + uid_label(self_) + " (mavbond runs as it)";
        if (exe_ != 0 && exe_ != self_)
            others += " or " + uid_label(exe_) + " (it owns mavbond's executable)";
        return std::string(what) + " " + path + " is owned by " + uid_label(uid) + ", not by " +
               others + ": whoever owns a plugin, or a directory or symlink on the way to it, "
               "may run code in mavbond";
    }

private:
    uid_t self_;
    uid_t exe_;
};

enum class Role { Ancestor, PluginDir, File };

/// Writable only by its owner: no one else may replace or change it.
std::optional<std::string> writable_by_others(const struct stat& st, Role role,
                                              const std::string& path) {
    const bool group = st.st_mode & S_IWGRP;
    const bool other = st.st_mode & S_IWOTH;
    // A sticky directory lets others add entries but not replace anyone else's, and the next
    // entry on the way is checked in turn. The plugin directory itself must be closed: any
    // name missing there could be someone else's plugin tomorrow.
    const bool sticky_ok = role == Role::Ancestor && (st.st_mode & S_ISVTX);
    if (sticky_ok || (!group && !other))
        return std::nullopt;
    const char* what = role == Role::File ? "plugin" : role == Role::PluginDir ? "plugin directory"
                                                                              : "directory";
    return std::string(what) + " " + path + " may be written by others than its owner (mode " +
           mode_text(st.st_mode) + ")";
}

std::string join(const std::string& dir, const std::string& name) {
    return dir == "/" ? "/" + name : dir + "/" + name;
}

std::string parent(const std::string& dir) {
    auto slash = dir.rfind('/');
    return slash == 0 || slash == std::string::npos ? "/" : dir.substr(0, slash);
}

void push_components(std::deque<std::string>& todo, const std::string& path) {
    std::deque<std::string> parts;
    size_t start = 0;
    while (start <= path.size()) {
        size_t end = path.find('/', start);
        if (end == std::string::npos)
            end = path.size();
        std::string part = path.substr(start, end - start);
        if (!part.empty() && part != ".")
            parts.push_back(std::move(part));
        start = end + 1;
    }
    todo.insert(todo.begin(), parts.begin(), parts.end());
}

}  // namespace

Result<TrustedFile> open_trusted_file(const std::string& dir, const std::string& file_name) {
    const Owners owners;
    std::string start = dir;
    if (start.empty() || start.front() != '/') {
        std::array<char, PATH_MAX> cwd{};
        if (!getcwd(cwd.data(), cwd.size()))
            return make_error(std::string("getcwd: ") + strerror(errno));
        start = std::string(cwd.data()) + "/" + start;
    }
    // The directory's own components, then a marker (where the walk has reached the plugin
    // directory), then the file.
    const std::string kFileMarker(1, '\0');
    std::deque<std::string> todo;
    push_components(todo, start);
    todo.push_back(kFileMarker);
    todo.push_back(file_name);

    std::string done = "/";
    struct stat st {};
    if (lstat("/", &st) < 0)
        return make_error(std::string("/: ") + strerror(errno));
    if (!owners.trusted(st.st_uid))
        return make_error(owners.refusal("directory", "/", st.st_uid));
    int symlinks = 0;
    bool at_file = false;
    while (!todo.empty()) {
        std::string part = std::move(todo.front());
        todo.pop_front();
        if (part == kFileMarker) {
            // Checked on the way (as an ancestor, if a ".." led back to it): the plugin
            // directory itself is held to more.
            if (lstat(done.c_str(), &st) < 0)
                return make_error(done + ": " + strerror(errno));
            if (auto why = writable_by_others(st, Role::PluginDir, done))
                return make_error(*why);
            at_file = true;
            continue;
        }
        if (part == "..") {
            done = parent(done);  // a prefix of the path already checked
            continue;
        }
        const std::string path = join(done, part);
        if (lstat(path.c_str(), &st) < 0)
            return make_error(path + ": " + strerror(errno));
        if (S_ISLNK(st.st_mode)) {
            // Its directory is checked (done); the link itself must be a trusted one too.
            if (!owners.trusted(st.st_uid))
                return make_error(owners.refusal("symlink", path, st.st_uid));
            if (++symlinks > kMaxSymlinks)
                return make_error(path + ": too many levels of symbolic links");
            std::array<char, PATH_MAX> target{};
            ssize_t n = readlink(path.c_str(), target.data(), target.size() - 1);
            if (n < 0)
                return make_error(path + ": " + strerror(errno));
            std::string to(target.data(), static_cast<size_t>(n));
            if (!to.empty() && to.front() == '/')
                done = "/";
            push_components(todo, to);
            continue;
        }
        const bool last = todo.empty();
        if (!owners.trusted(st.st_uid))
            return make_error(owners.refusal(last ? "plugin" : "directory", path, st.st_uid));
        if (!last && !S_ISDIR(st.st_mode))
            return make_error(path + ": not a directory");
        const Role role = last                        ? Role::File
                          : todo.front() == kFileMarker ? Role::PluginDir
                                                        : Role::Ancestor;
        if (auto why = writable_by_others(st, role, path))
            return make_error(*why);
        done = path;
    }
    if (!at_file || !S_ISREG(st.st_mode))
        return make_error(done + ": not a regular file");

    // The checks were on names; what is loaded is this descriptor, checked again: the same
    // file as walked, still as it was.
    const struct stat walked = st;
    UniqueFd fd(open(done.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NOCTTY));
    if (!fd)
        return make_error(done + ": " + strerror(errno));
    if (fstat(fd.get(), &st) < 0)
        return make_error(done + ": " + strerror(errno));
    if (st.st_dev != walked.st_dev || st.st_ino != walked.st_ino || !S_ISREG(st.st_mode))
        return make_error(done + ": replaced while it was being checked");
    if (!owners.trusted(st.st_uid))
        return make_error(owners.refusal("plugin", done, st.st_uid));
    if (auto why = writable_by_others(st, Role::File, done))
        return make_error(*why);
    return TrustedFile{std::move(fd), done};
}

}  // namespace mavbond
