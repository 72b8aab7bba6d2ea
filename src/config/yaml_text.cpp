#include "config/yaml_text.h"

#include <yaml-cpp/eventhandler.h>
#include <yaml-cpp/exceptions.h>
#include <yaml-cpp/yaml.h>

#include <cstdio>
#include <sstream>
#include <string_view>

namespace mavbond {

std::string format_at(const std::string& name, const YAML::Mark& mark, const std::string& what) {
    int line = mark.is_null() ? 1 : mark.line + 1;
    int column = mark.is_null() ? 1 : mark.column + 1;
    return name + ":" + std::to_string(line) + ":" + std::to_string(column) + ": " + what;
}

/// YAML allows no control character but tab and line breaks (its c-printable set), and
/// yaml-cpp misreads them: a NUL ends a scalar early, and the error then points past the end
/// of the line and carries the NUL into the message (found by tests/fuzz/fuzz_config). So the
/// first one is refused here, where it is. Lines and columns count bytes, as yaml-cpp's do.
std::optional<std::string> control_character_error(const std::string& text,
                                                   const std::string& name) {
    int line = 1;
    size_t line_start = 0;
    for (size_t i = 0; i < text.size(); ++i) {
        const auto c = static_cast<unsigned char>(text[i]);
        if (c == '\n') {
            ++line;
            line_start = i + 1;
        } else if ((c < 0x20 && c != '\t' && c != '\r') || c == 0x7F) {
            char what[64];
            std::snprintf(what, sizeof what, "control character 0x%02X is not allowed in YAML", c);
            return name + ":" + std::to_string(line) + ":" + std::to_string(i - line_start + 1) +
                   ": " + what;
        }
    }
    return std::nullopt;
}

namespace {

/// Where the documents of a YAML stream start, and their root nodes. It replaces LoadAll(),
/// which loops forever, allocating, on a token no document can take, such as a stray ','
/// (yaml-cpp issue #1040; found by tests/fuzz/fuzz_config): the parser hands out empty
/// documents that all start at that token.
class DocumentMarks : public YAML::EventHandler {
public:
    struct Document {
        YAML::Mark start;
        YAML::Mark root = YAML::Mark::null_mark();
    };
    std::vector<Document> documents;

    void OnDocumentStart(const YAML::Mark& mark) override { documents.push_back({mark}); }
    void OnDocumentEnd() override {}
    void OnNull(const YAML::Mark& mark, YAML::anchor_t) override { node(mark); }
    void OnAlias(const YAML::Mark& mark, YAML::anchor_t) override { node(mark); }
    void OnScalar(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                  const std::string&) override {
        node(mark);
    }
    void OnSequenceStart(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                         YAML::EmitterStyle::value) override {
        node(mark);
    }
    void OnSequenceEnd() override {}
    void OnMapStart(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                    YAML::EmitterStyle::value) override {
        node(mark);
    }
    void OnMapEnd() override {}

private:
    void node(const YAML::Mark& mark) {
        if (!documents.empty() && documents.back().root.is_null())
            documents.back().root = mark;
    }
};

}  // namespace

/// The error for a text that is not exactly one YAML document, if it is not.
std::optional<std::string> document_error(const std::string& text, const std::string& name) {
    std::istringstream in(text);
    YAML::Parser parser(in);
    DocumentMarks marks;
    // Three are enough: a second document, or one starting where the one before did.
    for (int i = 0; i < 3 && parser.HandleNextDocument(marks); ++i) {
    }
    const auto& docs = marks.documents;
    for (size_t k = 1; k < docs.size(); ++k) {
        if (docs[k].start.pos == docs[k - 1].start.pos) {
            const auto pos = static_cast<size_t>(docs[k - 1].start.pos);
            const char c = pos < text.size() ? text[pos] : ' ';
            return format_at(name, docs[k - 1].start,
                             c > ' ' && c < 0x7F ? std::string("unexpected '") + c + "'"
                                                 : std::string("unexpected text"));
        }
    }
    if (docs.size() > 1) {
        return format_at(name, docs[1].root.is_null() ? docs[1].start : docs[1].root,
                         "only one YAML document is allowed (found a second one after '---')");
    }
    return std::nullopt;
}

namespace {

/// Line `n` (0-based) of `text`, without its line break; empty past the end.
std::string_view line_at(const std::string& text, int n) {
    size_t begin = 0;
    for (int i = 0; i < n; i++) {
        begin = text.find('\n', begin);
        if (begin == std::string::npos)
            return {};
        begin++;
    }
    size_t end = text.find('\n', begin);
    return std::string_view(text).substr(begin, end == std::string::npos ? std::string::npos
                                                                         : end - begin);
}

/// Where a line's key starts (0-based), past its indentation and a "- " item mark; npos for a
/// line that is blank or a comment.
size_t key_column(std::string_view line) {
    size_t i = line.find_first_not_of(' ');
    if (i != std::string_view::npos && line[i] == '-' && i + 1 < line.size() && line[i + 1] == ' ')
        i = line.find_first_not_of(' ', i + 1);
    if (i == std::string_view::npos || line[i] == '#' || line[i] == '\r')
        return std::string_view::npos;
    return i;
}

/// The key column of the nearest line above `n` that has one.
size_t key_column_above(const std::string& text, int n) {
    for (int i = n - 1; i >= 0; i--) {
        if (size_t c = key_column(line_at(text, i)); c != std::string_view::npos)
            return c;
    }
    return std::string_view::npos;
}

std::string column_text(size_t zero_based) { return "column " + std::to_string(zero_based + 1); }

/// What is wrong, in words, for the yaml-cpp errors a hand-edited config meets; "" for others.
std::string plain_account(const std::string& text, const YAML::Mark& mark, const std::string& what) {
    const std::string_view line = line_at(text, mark.line);
    const size_t indent_end = line.find_first_not_of(" \t");
    if (line.substr(0, indent_end).find('\t') != std::string_view::npos)
        return "this line is indented with a tab: YAML indents with spaces only";
    // YAML reads `address: [::1]:14550` as a list and then fails on what follows.
    if (auto open = line.find('['); open != std::string_view::npos &&
                                    line.find("]:", open) != std::string_view::npos)
        return "an IPv6 address in brackets is quoted in YAML: address: \"[::1]:14550\"";
    const size_t here = key_column(line);
    const size_t above = key_column_above(text, mark.line);
    const auto col = static_cast<size_t>(mark.column);
    if (what == YAML::ErrorMsg::MAP_VALUE) {
        // A key on this line before the ':' complained of: that ':' is inside its value.
        const size_t colon = line.find(": ", here == std::string_view::npos ? 0 : here);
        if (colon != std::string_view::npos && colon < col)
            return "a value that holds ': ' must be quoted (\"...\")";
        if (here != std::string_view::npos && above != std::string_view::npos && here > above)
            return "this line's key (" + column_text(here) + ") is indented deeper than the key "
                   "above it (" + column_text(above) + "), which has its value already: the keys "
                   "of one map start in the same column";
    }
    if ((what == YAML::ErrorMsg::END_OF_MAP || what == YAML::ErrorMsg::END_OF_SEQ) &&
        here != std::string_view::npos && above != std::string_view::npos)
        return "this line's key (" + column_text(here) + ") lines up with no map above it (the "
               "key above starts at " + column_text(above) + "): the keys of one map start in the "
               "same column, a list's items too";
    if (what == YAML::ErrorMsg::END_OF_MAP_FLOW)
        return "a '{' before this has no closing '}'";
    if (what == YAML::ErrorMsg::END_OF_SEQ_FLOW)
        return "a '[' before this has no closing ']'";
    if (what == YAML::ErrorMsg::BLOCK_ENTRY)
        return "a '- ' list item where none can start: indent it under the key whose list it is";
    if (what.starts_with(YAML::ErrorMsg::INVALID_ESCAPE))
        return "in double quotes a backslash starts an escape (\\n, \\t): write \\\\ for one, or "
               "use single quotes";
    return "";
}

}  // namespace

std::string yaml_syntax_error(const std::string& text, const std::string& name,
                              const YAML::Mark& mark, const std::string& what) {
    const std::string account = mark.is_null() ? "" : plain_account(text, mark, what);
    return format_at(name, mark, account.empty() ? what : account + " (YAML: " + what + ")");
}

}  // namespace mavbond
