// The rig's HX711s (pins::kRigChannels) read without blocking: the main loop calls poll() every pass, and poll() reads
// at most one channel, and only one whose conversion is ready (DOUT low), so a pass never
// waits for the 80 Hz conversions.
#pragma once

#include "src/core/firmware.h"

class LoadCells {
 public:
  void begin();
  // Reads the next ready channel into inputs.raw_counts and sets its new_sample_mask bit.
  void poll(twinfw::Inputs& inputs);

 private:
  int32_t read(int channel);
  int next_ = 0;
};
