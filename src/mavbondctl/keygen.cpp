#include "keygen.h"

#include <fcntl.h>
#include <pwd.h>
#include <sys/random.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <string>

namespace mavbond {
namespace {

constexpr int kExitNoUser = 67;     // EX_NOUSER
constexpr int kExitCantCreat = 73;  // EX_CANTCREAT

bool write_all(int fd, const char* data, size_t len) {
    while (len > 0) {
        ssize_t n = write(fd, data, len);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            return false;
        data += n;
        len -= static_cast<size_t>(n);
    }
    return true;
}

}  // namespace

int keygen(const std::string& path, const std::string& owner, bool owner_given) {
    const passwd* pw = getpwnam(owner.c_str());
    if (!pw && owner_given) {
        fprintf(stderr, "mavbondctl: keygen: no user '%s' here\n", owner.c_str());
        return kExitNoUser;
    }
    // O_EXCL: an existing key is never replaced (the other side still holds it).
    int fd = open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC | O_NOFOLLOW, 0600);
    if (fd < 0) {
        int err = errno;
        fprintf(stderr, "mavbondctl: keygen: cannot create %s: %s%s\n", path.c_str(), strerror(err),
                err == EEXIST ? " (not overwritten: both sides hold the key in use; remove the "
                                "file first to make a new one, then copy it to both)"
                              : "");
        return kExitCantCreat;
    }
    auto fail = [&](const std::string& what, const char* hint = "") {
        int err = errno;
        fprintf(stderr, "mavbondctl: keygen: %s: %s (%s removed%s)\n", what.c_str(),
                strerror(err), path.c_str(), hint);
        close(fd);
        unlink(path.c_str());
        return kExitCantCreat;
    };
    // The mode whatever the umask; the owner before a byte of the key is in the file.
    if (fchmod(fd, 0600) < 0)
        return fail("cannot set the mode of " + path);
    if (pw && fchown(fd, pw->pw_uid, pw->pw_gid) < 0)
        return fail("cannot give " + path + " to user " + owner, "; run it as root");
    unsigned char key[32];
    size_t got = 0;
    while (got < sizeof key) {
        ssize_t n = getrandom(key + got, sizeof key - got, 0);
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0)
            return fail("no random bytes");
        got += static_cast<size_t>(n);
    }
    char hex[2 * sizeof key + 2];
    for (size_t i = 0; i < sizeof key; i++)
        snprintf(hex + 2 * i, 3, "%02x", key[i]);
    hex[2 * sizeof key] = '\n';
    hex[2 * sizeof key + 1] = '\0';
    explicit_bzero(key, sizeof key);
    const bool written = write_all(fd, hex, 2 * sizeof key + 1) && fsync(fd) == 0;
    explicit_bzero(hex, sizeof hex);
    if (!written)
        return fail("cannot write " + path);
    close(fd);
    printf("%s: a new 32-byte key, mode 0600, owner %s\n", path.c_str(),
           pw ? owner.c_str() : "you (no user mavbond here)");
    printf("Copy this same file to the other gateway (the same path there, mode 0600, owner %s)\n"
           "and name it in both configurations: bonds: - {name: ..., signing: {key_file: %s}}\n",
           owner.c_str(), path.c_str());
    return 0;
}

}  // namespace mavbond
