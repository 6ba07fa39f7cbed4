/* Just enough of the Arduino core for `g++ -fsyntax-only` on firmware/skinloc_muca (a host
 * check of the sketch; nothing here runs). */
#pragma once
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

struct HardwareSerialStub {
  void begin(unsigned long baud);
  int available();
  int read();
  size_t write(const uint8_t *data, size_t len);
  template <class T> size_t print(T value);
  template <class T> size_t println(T value);
  size_t println();
};
extern HardwareSerialStub Serial;
void delay(unsigned long ms);
