/*
 * ft5x06.h - a small raw-mode driver of the FocalTech FT5x06 touch controller over Wire.
 *
 * Only what skinloc needs: find the controller, put it in test (raw) mode, set the analog gain,
 * start a raw scan, and read the raw counts of one TX line at a time. No heap, no text output:
 * every function returns a status and the sketch decides what to say.
 *
 * Register map as the Muca project drives the controller (I2C address 0x38, 400 kHz, register
 * writes followed by a repeated start):
 *
 *   0x00  mode: 0x00 normal, 0x40 test, 0xC0 test + start a raw scan (bit 7 clears when done)
 *   0x01  TX line to read: 20 - tx (the controller numbers the TX lines in reverse)
 *   0x07  analog gain, 1-31, written in test mode
 *   0x10  raw counts of the selected TX line: 12 x 16-bit big-endian values, one per RX line
 */
#ifndef SKINLOC_FT5X06_H
#define SKINLOC_FT5X06_H

#include <Arduino.h>
#include <Wire.h>

#define FT_ADDR 0x38
#define FT_REG_MODE 0x00
#define FT_REG_TX 0x01
#define FT_REG_GAIN 0x07
#define FT_REG_RAW 0x10
#define FT_MODE_TEST 0x40
#define FT_MODE_SCAN 0xC0
#define FT_N_TX 21
#define FT_N_RX 12
#define FT_GAIN_MIN 1
#define FT_GAIN_MAX 31
#define FT_SCAN_TIMEOUT_MS 100  // a raw scan takes a few ms; 100 ms means it has stopped
#define FT_TX_SETTLE_US 50      // after selecting a TX line, before reading it

enum ft_status : uint8_t {
  FT_OK = 0,       // the controller answers and scans
  FT_MISSING = 1,  // nothing acknowledges 0x38: wiring, supply, or no controller
  FT_SILENT = 2,   // it acknowledges but does not scan (or reads back nonsense)
};

// Write one register; true when every byte was acknowledged.
static bool ft_write(uint8_t reg, uint8_t value) {
  Wire.beginTransmission(FT_ADDR);
  Wire.write(reg);
  Wire.write(value);
  return Wire.endTransmission() == 0;
}

// Point at a register and read n bytes of it (repeated start); true when all n came.
static bool ft_read(uint8_t reg, uint8_t n) {
  Wire.beginTransmission(FT_ADDR);
  Wire.write(reg);
  if (Wire.endTransmission(false) != 0) return false;
  return Wire.requestFrom((uint8_t)FT_ADDR, n) == n;
}

static ft_status ft_scan();

// Is anything at 0x38, does it take test mode, and does it scan? (Also the `c` command.)
static ft_status ft_begin(uint8_t gain) {
  Wire.beginTransmission(FT_ADDR);
  if (Wire.endTransmission() != 0) return FT_MISSING;
  if (!ft_write(FT_REG_MODE, FT_MODE_TEST)) return FT_MISSING;
  delay(1);
  if (!ft_read(FT_REG_MODE, 1) || (Wire.read() & 0x70) != FT_MODE_TEST) return FT_SILENT;
  if (!ft_write(FT_REG_GAIN, gain)) return FT_MISSING;
  return ft_scan();  // a trial scan: a controller that acknowledges but never scans is no use
}

// Set the analog gain (the caller keeps it in FT_GAIN_MIN..FT_GAIN_MAX).
static ft_status ft_set_gain(uint8_t gain) {
  if (!ft_write(FT_REG_MODE, FT_MODE_TEST)) return FT_MISSING;
  return ft_write(FT_REG_GAIN, gain) ? FT_OK : FT_MISSING;
}

// Start a raw scan and wait until the controller has finished it.
static ft_status ft_scan() {
  if (!ft_write(FT_REG_MODE, FT_MODE_SCAN)) return FT_MISSING;
  const unsigned long start = millis();
  for (;;) {
    delayMicroseconds(200);
    if (!ft_read(FT_REG_MODE, 1)) return FT_MISSING;
    if ((Wire.read() & 0x80) == 0) return FT_OK;
    if (millis() - start > FT_SCAN_TIMEOUT_MS) return FT_SILENT;
  }
}

// Read the raw counts of TX line `tx` (0-20) into out[], keeping the RX lines set in rx_mask.
static ft_status ft_read_tx(uint8_t tx, uint16_t rx_mask, uint16_t *out) {
  if (!ft_write(FT_REG_TX, (uint8_t)(FT_N_TX - 1 - tx))) return FT_MISSING;
  delayMicroseconds(FT_TX_SETTLE_US);
  if (!ft_read(FT_REG_RAW, 2 * FT_N_RX)) return FT_MISSING;
  for (uint8_t rx = 0; rx < FT_N_RX; rx++) {
    const uint8_t hi = (uint8_t)Wire.read();
    const uint8_t lo = (uint8_t)Wire.read();
    if (rx_mask & (1u << rx)) *out++ = (uint16_t)((hi << 8) | lo);
  }
  return FT_OK;
}

#endif /* SKINLOC_FT5X06_H */
