// The fuzz targets' assertion: a broken invariant is a crash, so libFuzzer saves the input and
// the replay test (replay_main.cpp) fails on it. Unlike assert(), it is never compiled out.
#pragma once

#include <cstdio>
#include <cstdlib>

#define FUZZ_CHECK(cond, ...)                                                        \
    do {                                                                             \
        if (!(cond)) {                                                               \
            std::fprintf(stderr, "%s:%d: invariant broken: %s: ", __FILE__, __LINE__, \
                         #cond);                                                     \
            std::fprintf(stderr, __VA_ARGS__);                                       \
            std::fputc('\n', stderr);                                                \
            std::abort();                                                            \
        }                                                                            \
    } while (0)
