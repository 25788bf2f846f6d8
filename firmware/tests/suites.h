// One entry point per test file.
#pragma once

void test_units();
void test_pid();
void test_codec();
void test_controller();
void test_firmware();
void test_safety();
void test_guard();
void test_channels();
