// Test frames encoded by pymavlink at build time (gen_vectors.py), loaded by label.
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

struct Vector {
    std::string label;
    int version = 0;
    uint32_t msgid = 0;
    int seq = 0;
    int sysid = 0;
    int compid = 0;
    int target_system = -1;
    int target_component = -1;
    bool is_signed = false;
    size_t payload_len = 0;
    Bytes bytes;
};

inline Bytes from_hex(const std::string& hex) {
    Bytes out;
    for (size_t i = 0; i + 1 < hex.size(); i += 2)
        out.push_back(static_cast<uint8_t>(std::stoul(hex.substr(i, 2), nullptr, 16)));
    return out;
}

/// The vectors file: $MAVBOND_MAVLINK_VECTORS, else the path compiled in by meson.
inline const std::vector<Vector>& vectors() {
    static const std::vector<Vector> all = [] {
        const char* env = std::getenv("MAVBOND_MAVLINK_VECTORS");
        const std::string path = env != nullptr ? env : MAVBOND_MAVLINK_VECTORS;
        std::ifstream in(path);
        if (!in)
            throw std::runtime_error("cannot open test vectors " + path);
        std::vector<Vector> out;
        std::string line;
        while (std::getline(in, line)) {
            if (line.empty() || line[0] == '#')
                continue;
            std::istringstream ls(line);
            Vector v;
            int is_signed = 0;
            std::string hex;
            ls >> v.label >> v.version >> v.msgid >> v.seq >> v.sysid >> v.compid >>
                v.target_system >> v.target_component >> is_signed >> v.payload_len >> hex;
            if (!ls)
                throw std::runtime_error("bad vector line: " + line);
            v.is_signed = is_signed != 0;
            v.bytes = from_hex(hex);
            out.push_back(std::move(v));
        }
        return out;
    }();
    return all;
}

inline const Vector& vec(const std::string& label) {
    for (const auto& v : vectors()) {
        if (v.label == label)
            return v;
    }
    throw std::runtime_error("no test vector " + label);
}

/// Vectors whose label starts with prefix.
inline std::vector<const Vector*> vectors_with_prefix(const std::string& prefix) {
    std::vector<const Vector*> out;
    for (const auto& v : vectors()) {
        if (v.label.rfind(prefix, 0) == 0)
            out.push_back(&v);
    }
    return out;
}

}  // namespace mavbond::test
