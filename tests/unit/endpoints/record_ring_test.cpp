// RecordRing: records come out whole, in order, across the wrap, with a producer and a
// consumer on two threads; a full ring refuses a record and stores nothing of it.
#include "endpoints/record_ring.h"

#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <cstring>
#include <thread>
#include <vector>

namespace mavbond {
namespace {

std::vector<uint8_t> pop_one(RecordRing& ring) {
    std::vector<uint8_t> out(RecordRing::kMaxRecord);
    out.resize(ring.pop(out.data()));
    return out;
}

TEST(RecordRing, HeadThenBodyInOrderAcrossTheWrap) {
    RecordRing ring(256);
    ASSERT_EQ(256u, ring.capacity());
    std::array<uint8_t, 2> head{0xAA, 0xBB};
    for (uint8_t round = 0; round < 50; round++) {  // 50 x 3 records of 2+2+~40 bytes wrap often
        for (uint8_t i = 0; i < 3; i++) {
            std::vector<uint8_t> body(40 + i, static_cast<uint8_t>(round + i));
            ASSERT_TRUE(ring.push(head, body));
        }
        for (uint8_t i = 0; i < 3; i++) {
            std::vector<uint8_t> want = {0xAA, 0xBB};
            want.insert(want.end(), 40 + i, static_cast<uint8_t>(round + i));
            ASSERT_EQ(want, pop_one(ring)) << "round " << int(round);
        }
        ASSERT_TRUE(pop_one(ring).empty());
        ASSERT_EQ(0u, ring.used());
    }
}

TEST(RecordRing, FullRefusesWholeRecords) {
    RecordRing ring(100);  // rounded up to 128
    std::array<uint8_t, 8> head{};
    std::vector<uint8_t> body(50, 7);  // 2 + 8 + 50 = 60 bytes a record
    EXPECT_TRUE(ring.push(head, body));
    EXPECT_TRUE(ring.push(head, body));
    EXPECT_FALSE(ring.push(head, body));
    EXPECT_EQ(120u, ring.used());
    EXPECT_EQ(58u, pop_one(ring).size());
    EXPECT_TRUE(ring.push(head, body));  // room again once the consumer took one
    EXPECT_EQ(58u, pop_one(ring).size());
    EXPECT_EQ(58u, pop_one(ring).size());
    EXPECT_TRUE(pop_one(ring).empty());
}

TEST(RecordRing, TwoThreadsLoseAndReorderNothing) {
    RecordRing ring(4096);
    constexpr uint32_t kRecords = 200000;
    std::thread consumer_thread;
    std::vector<uint32_t> got;
    got.reserve(kRecords);
    std::atomic<bool> producer_done{false};
    consumer_thread = std::thread([&] {
        std::vector<uint8_t> buf(RecordRing::kMaxRecord);
        // Bounded: stops once the producer is done and the ring is empty. `done` is read once,
        // before the pop: read again after an empty pop, it could turn true between the two
        // reads and end the loop with the producer's last records still in the ring.
        while (true) {
            bool done = producer_done.load();
            size_t n = ring.pop(buf.data());
            if (n == 0) {
                if (done)
                    break;
                std::this_thread::yield();
                continue;
            }
            uint32_t v;
            std::memcpy(&v, buf.data(), sizeof v);
            EXPECT_EQ(4u + v % 200, n);
            got.push_back(v);
        }
    });
    for (uint32_t i = 0; i < kRecords; i++) {
        std::vector<uint8_t> body(4 + i % 200);
        std::memcpy(body.data(), &i, sizeof i);
        while (!ring.push(std::span<const uint8_t>(body.data(), 0), body))
            std::this_thread::yield();
    }
    producer_done.store(true);
    consumer_thread.join();
    ASSERT_EQ(kRecords, got.size());
    for (uint32_t i = 0; i < kRecords; i++)
        ASSERT_EQ(i, got[i]);
}

}  // namespace
}  // namespace mavbond
