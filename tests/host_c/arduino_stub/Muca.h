/* The part of the Muca library's API that skinloc_muca.ino uses (raw mode, line selection),
 * declared for a host syntax check of the sketch. */
#pragma once
#include "Arduino.h"

#define NUM_ROWS 21
#define NUM_COLUMNS 12

class Muca {
 public:
  void init(bool raw = false);
  bool updated();
  void useRawData(bool useRaw);
  void selectLines(bool *rx, bool *tx);
  void setGain(int gain);
  short grid[NUM_ROWS * NUM_COLUMNS];
  uint8_t num_TX;
  uint8_t num_RX;
};
