// The YAML text before it is a config: what yaml-cpp cannot be trusted with (control
// characters, more than one document, a stray token LoadAll() loops on), and its syntax errors
// said plainly, with file:line:column and what to do.
#pragma once

#include <yaml-cpp/mark.h>

#include <optional>
#include <string>

namespace mavbond {

/// "NAME:LINE:COLUMN: what" (1-based; a null mark is the file's start).
std::string format_at(const std::string& name, const YAML::Mark& mark, const std::string& what);
/// The first control character YAML does not allow, if any, as an error at its place.
std::optional<std::string> control_character_error(const std::string& text,
                                                   const std::string& name);
/// The error for a text that is not exactly one YAML document, if it is not.
std::optional<std::string> document_error(const std::string& text, const std::string& name);
/// A syntax error yaml-cpp threw (its message `what` at `mark`) as "NAME:LINE:COLUMN: " and
/// a plain account of what is wrong on that line and how to write it, then yaml-cpp's own
/// words in parentheses.
std::string yaml_syntax_error(const std::string& text, const std::string& name,
                              const YAML::Mark& mark, const std::string& what);

}  // namespace mavbond
