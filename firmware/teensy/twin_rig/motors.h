// DRV8871 H-bridges driven from the firmware's outputs.
#pragma once

#include "src/core/firmware.h"

class Motors {
 public:
  void begin();
  void apply(const twinfw::Outputs& outputs);
};
