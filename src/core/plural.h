// "1 bond", "2 bonds": a count and its noun, as log lines and messages say it.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

namespace mavbond {

/// `nouns` for an irregular plural; by default the noun and an "s".
inline std::string plural(uint64_t n, std::string_view noun, std::string_view nouns = {}) {
    std::string word(n == 1 ? noun : nouns.empty() ? noun : nouns);
    if (n != 1 && nouns.empty())
        word += 's';
    return std::to_string(n) + " " + word;
}

}  // namespace mavbond
