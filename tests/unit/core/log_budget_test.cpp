#include "core/log_budget.h"

#include <gtest/gtest.h>

namespace mavbond {
namespace {

class LogBudgetTest : public ::testing::Test {
protected:
    void SetUp() override {
        level_ = log_level();
        log_set_level(LogLevel::Info);
    }
    void TearDown() override { log_set_level(level_); }
    LogLevel level_{};
};

TEST_F(LogBudgetTest, LetsABurstThroughEachPeriodAndCountsTheRest) {
    LogBudget budget(2, seconds(10));
    TimePoint t = Clock::now();
    EXPECT_TRUE(budget.allow(t));
    EXPECT_EQ("", budget.left_out_note());
    EXPECT_TRUE(budget.allow(t + seconds(1)));
    for (int i = 0; i < 500; i++)  // a flood of events
        EXPECT_FALSE(budget.allow(t + seconds(2)));
    EXPECT_TRUE(budget.allow(t + seconds(10)));
    EXPECT_EQ(" (500 more like it not logged)", budget.left_out_note());
    EXPECT_EQ("", budget.left_out_note()) << "said once";
}

TEST_F(LogBudgetTest, AtDebugLevelEveryLineGoes) {
    log_set_level(LogLevel::Debug);
    LogBudget budget(1, seconds(10));
    TimePoint t = Clock::now();
    for (int i = 0; i < 5; i++)
        EXPECT_TRUE(budget.allow(t));
}

}  // namespace
}  // namespace mavbond
