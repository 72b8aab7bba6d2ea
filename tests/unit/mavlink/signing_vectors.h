// SHA-256 digests (hashlib) and signed frames (pymavlink) made at build time by
// gen_signing_vectors.py.
#pragma once

#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace mavbond::test {

using Bytes = std::vector<uint8_t>;

inline Bytes bytes_from_hex(const std::string& hex) {
    Bytes out;
    for (size_t i = 0; i + 1 < hex.size(); i += 2)
        out.push_back(static_cast<uint8_t>(std::stoul(hex.substr(i, 2), nullptr, 16)));
    return out;
}

struct SignedFrame {
    int link_id = 0;
    uint64_t timestamp = 0;
    Bytes bytes;
};

struct SigningVectors {
    std::vector<std::pair<Bytes, Bytes>> sha;  // input, digest
    Bytes key;
    std::map<std::string, SignedFrame> frames;

    const SignedFrame& frame(const std::string& label) const {
        auto it = frames.find(label);
        if (it == frames.end())
            throw std::runtime_error("no signing vector " + label);
        return it->second;
    }
};

/// $MAVBOND_SIGNING_VECTORS, else the path compiled in by meson.
inline const SigningVectors& signing_vectors() {
    static const SigningVectors all = [] {
        const char* env = std::getenv("MAVBOND_SIGNING_VECTORS");
        const std::string path = env != nullptr ? env : MAVBOND_SIGNING_VECTORS;
        std::ifstream in(path);
        if (!in)
            throw std::runtime_error("cannot open signing vectors " + path);
        SigningVectors v;
        std::string line;
        while (std::getline(in, line)) {
            if (line.empty() || line[0] == '#')
                continue;
            std::istringstream ls(line);
            std::string kind;
            ls >> kind;
            if (kind == "sha") {
                std::string input, digest;
                ls >> input >> digest;
                v.sha.emplace_back(bytes_from_hex(input == "-" ? "" : input), bytes_from_hex(digest));
            } else if (kind == "key") {
                std::string hex;
                ls >> hex;
                v.key = bytes_from_hex(hex);
            } else if (kind == "frame") {
                std::string label, hex;
                SignedFrame f;
                ls >> label >> f.link_id >> f.timestamp >> hex;
                f.bytes = bytes_from_hex(hex);
                v.frames[label] = f;
            }
            if (!ls)
                throw std::runtime_error("bad signing vector line: " + line);
        }
        if (v.sha.empty() || v.key.size() != 32 || v.frames.empty())
            throw std::runtime_error("incomplete signing vectors in " + path);
        return v;
    }();
    return all;
}

}  // namespace mavbond::test
