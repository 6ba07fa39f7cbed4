// Host syntax check of the Arduino sketch against tests/host_c/arduino_stub (see test_framing).
#include "Arduino.h"
#include "skinloc_muca.ino"
