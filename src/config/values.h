// The config's value syntax: numbers, sizes, rates, durations, percentages, addresses and
// message names as the YAML writes them, each parsed to its value or refused (nullopt, or an
// error text for an address). What config.h declares of them is defined here too.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace mavbond {

constexpr uint32_t kMaxMessageId = 0xFFFFFF;          // MAVLink v2 msgid is 24 bits
constexpr uint64_t kMinTxRate = 100;                  // B/s: one largest frame in about 3 s
constexpr uint64_t kMaxTxRate = 1000u * 1000 * 1000;  // a typo guard

/// Parses a string of decimal digits; nullopt on anything else or overflow.
std::optional<uint64_t> parse_u64(std::string_view s);
/// "16384", "16k", "16KiB", "64M", "64MiB", "1G", "1GiB" -> bytes.
std::optional<uint64_t> parse_byte_size(std::string_view text);
/// "5kB/s", "5760B/s", "64KiB/s", "1MB/s" or "57600baud" -> bytes a second.
std::optional<uint64_t> parse_tx_rate_text(std::string_view text);
/// "10Hz", "0.5Hz" -> the rate, within (0, 1000].
std::optional<double> parse_hertz(std::string_view text);
/// "10%" -> 0.10: a percentage from 0 to 100, the % required.
std::optional<double> parse_percent(const std::string& text);
/// A message as the config names it: an id ("76") or a name ("COMMAND_LONG").
std::optional<uint32_t> message_id(const std::string& text);
/// "COMMAND_LONG (76)", or "76" for an id the message table does not know.
std::string message_label(uint32_t id);
/// 65536 -> "64KiB", 1073741824 -> "1GiB": the largest unit that divides it.
std::string format_size(uint64_t n);

}  // namespace mavbond
