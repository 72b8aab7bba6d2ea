// Runs a fuzz target's LLVMFuzzerTestOneInput over saved inputs, without libFuzzer: the normal
// (gcc) build replays every target's regression inputs and generated seeds this way in
// `meson test`, so a bug a fuzzer once found stays fixed on every machine.
//
// Usage: fuzz_TARGET_replay PATH...; a PATH is an input file or a directory of them (files
// whose name starts with '.' are skipped). A broken invariant aborts, naming the input; a
// missing PATH, or no input at all, fails.
#include <algorithm>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <unistd.h>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

namespace {

namespace fs = std::filesystem;

// The input being replayed, for the crash handler (which may only call write()).
char g_current[4096];

void name_input_and_die(int sig) {
    const char prefix[] = "\ncrashed while replaying: ";
    (void)!write(STDERR_FILENO, prefix, sizeof prefix - 1);
    (void)!write(STDERR_FILENO, g_current, std::strlen(g_current));
    (void)!write(STDERR_FILENO, "\n", 1);
    std::signal(sig, SIG_DFL);
    std::raise(sig);
}

bool is_input(const fs::path& p) {
    return fs::is_regular_file(p) && p.filename().string().front() != '.';
}

}  // namespace

int main(int argc, char** argv) {
    std::vector<fs::path> inputs;
    for (int i = 1; i < argc; ++i) {
        const fs::path arg = argv[i];
        if (fs::is_directory(arg)) {
            std::vector<fs::path> found;
            for (const auto& entry : fs::directory_iterator(arg)) {
                if (is_input(entry.path()))
                    found.push_back(entry.path());
            }
            std::sort(found.begin(), found.end());
            std::printf("%s: %zu inputs\n", arg.c_str(), found.size());
            inputs.insert(inputs.end(), found.begin(), found.end());
        } else if (is_input(arg)) {
            inputs.push_back(arg);
        } else {
            std::fprintf(stderr, "%s: no such input file or directory\n", arg.c_str());
            return 1;
        }
    }
    if (inputs.empty()) {
        std::fprintf(stderr, "no inputs to replay\n");
        return 1;
    }
    // Where a sanitizer already handles a signal, it reports and then aborts: keep its handler.
    for (int sig : {SIGABRT, SIGSEGV, SIGBUS, SIGFPE, SIGILL}) {
        struct sigaction current {};
        if (sigaction(sig, nullptr, &current) == 0 && current.sa_handler == SIG_DFL)
            std::signal(sig, name_input_and_die);
    }
    for (const fs::path& p : inputs) {
        std::snprintf(g_current, sizeof g_current, "%s", p.c_str());
        std::ifstream in(p, std::ios::binary);
        const std::vector<char> bytes{std::istreambuf_iterator<char>(in),
                                      std::istreambuf_iterator<char>()};
        if (!in.good() && !in.eof()) {
            std::fprintf(stderr, "%s: cannot read\n", p.c_str());
            return 1;
        }
        LLVMFuzzerTestOneInput(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size());
    }
    std::printf("replayed %zu inputs, every invariant held\n", inputs.size());
    return 0;
}
