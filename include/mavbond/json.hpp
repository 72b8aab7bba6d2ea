// A bounded JSON text writer for a plugin's status_json: writes what fits into the host's
// buffer and counts the whole length, so the host can retry with a larger buffer (the ABI's
// contract). FilterPlugin<T> hands one to T::status(JsonOut&), and to T::describe (plain text,
// written with raw()).
#ifndef MAVBOND_JSON_HPP
#define MAVBOND_JSON_HPP

#include <cstdarg>
#include <cstddef>
#include <cstdio>
#include <cstring>

namespace mavbond {

class JsonOut {
public:
    JsonOut(char* buf, size_t len) : buf_(buf), len_(len) {
        if (buf_ && len_)
            buf_[0] = '\0';
    }

    /// Appends formatted text as is (numbers, punctuation, keys known to need no escaping).
    __attribute__((format(printf, 2, 3))) void raw(const char* fmt, ...) {
        char tmp[256];
        va_list ap;
        va_start(ap, fmt);
        int n = vsnprintf(tmp, sizeof tmp, fmt, ap);
        va_end(ap);
        if (n <= 0)
            return;
        if (static_cast<size_t>(n) < sizeof tmp) {
            put(tmp, static_cast<size_t>(n));
            return;
        }
        // Longer than the scratch buffer: format again straight into place.
        va_start(ap, fmt);
        if (pos_ < len_)
            vsnprintf(buf_ + pos_, len_ - pos_, fmt, ap);
        va_end(ap);
        pos_ += static_cast<size_t>(n);
        terminate();
    }

    /// Appends a quoted, escaped string ("null" for nullptr).
    void str(const char* s) {
        if (!s) {
            put("null", 4);
            return;
        }
        put("\"", 1);
        for (; *s; s++) {
            auto c = static_cast<unsigned char>(*s);
            if (c == '"' || c == '\\') {
                char e[2] = {'\\', static_cast<char>(c)};
                put(e, 2);
            } else if (c < 0x20) {
                char e[8];
                snprintf(e, sizeof e, "\\u%04x", c);
                put(e, 6);
            } else {
                put(s, 1);
            }
        }
        put("\"", 1);
    }

    /// A finite number ("null" otherwise: JSON has no NaN).
    void num(double v, int decimals = 3) {
        if (v != v || v > 1e300 || v < -1e300)
            put("null", 4);
        else
            raw("%.*f", decimals, v);
    }

    size_t length() const { return pos_; }

private:
    void put(const char* s, size_t n) {
        if (pos_ < len_) {
            size_t room = len_ - pos_ - 1;
            memcpy(buf_ + pos_, s, n < room ? n : room);
        }
        pos_ += n;
        terminate();
    }
    void terminate() {
        if (len_)
            buf_[pos_ < len_ ? pos_ : len_ - 1] = '\0';
    }

    char* buf_;
    size_t len_;
    size_t pos_ = 0;
};

}  // namespace mavbond

#endif  // MAVBOND_JSON_HPP
