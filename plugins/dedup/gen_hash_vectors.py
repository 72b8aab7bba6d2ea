#!/usr/bin/env python3
"""Emit MurmurHash3 test vectors computed by the mmh3 package (an implementation independent
of ours), for dedup_test.

Usage: gen_hash_vectors.py OUTPUT

One vector per line: seed hex_key x86_32 x64_128_h1 x64_128_h2 (hashes in hex; h1 is the
first 8 bytes of the 16-byte digest read little-endian). An empty key is written as '-'.
The generator is seeded, so the file is the same on every build.
"""
import random
import sys

import mmh3


def main():
    rng = random.Random(20240611)
    lines = []
    lengths = list(range(0, 40)) + [rng.randint(0, 300) for _ in range(400)] + [255, 256, 300]
    for n in lengths:
        key = bytes(rng.getrandbits(8) for _ in range(n))
        seed = rng.choice([0, 1, 0xFFFFFFFF, rng.getrandbits(32)])
        h32 = mmh3.hash(key, seed, signed=False)
        h128 = mmh3.hash128(key, seed, x64arch=True, signed=False)
        # hash128 is the digest as one little-endian integer: h1 in the low 64 bits.
        h1 = h128 & (2**64 - 1)
        h2 = h128 >> 64
        lines.append(f"{seed:x} {key.hex() or '-'} {h32:08x} {h1:016x} {h2:016x}")
    with open(sys.argv[1], "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
