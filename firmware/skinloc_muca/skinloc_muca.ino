/*
 * skinloc_muca.ino - stream raw mutual-capacitance frames from a Muca board to skinloc.
 *
 * Board: an Arduino (Uno, Nano, Leonardo, Zero...) wired to a Muca breakout (FocalTech FT5x06,
 * up to 21 TX x 12 RX) over I2C; see firmware/README.md for wiring and flashing.
 * Library: Muca (Arduino Library Manager, or github.com/muca-board/Muca).
 *
 * Output: every frame the controller produces, either in skinloc's binary format
 * (docs/protocol.md, the default) or in the paper's text format (one line of comma-separated
 * counts, TX-major). Input: one command per line (newline-terminated):
 *
 *   v                 version, grid, format and gain, e.g. "skinloc_muca 1.0.0 grid 8x8 ..."
 *   f text|binary     switch the output format
 *   g N               set the analog gain (0-255; the Muca examples use 1-100)
 *   l TXMASK RXMASK   select lines, e.g. "l 111111110000000000000 111111110000" (1 = used);
 *                     the grid becomes the number of ones; masks shorter than 21 / 12 mean
 *                     that the remaining lines are unused
 *   c                 recalibrate: re-initialise the controller (re-applies lines and gain)
 *   ?                 list the commands
 *
 * Replies are single text lines ("ok ...", "error ..."); the host skips them in both formats.
 */
#include <Muca.h>

#include "skinloc_wire.h"

#ifndef SKINLOC_BAUD
#define SKINLOC_BAUD 1000000UL  // binary: the whole 21 x 12 grid at ~190 frames/s
#endif
#ifndef SKINLOC_DEFAULT_FORMAT_TEXT
#define SKINLOC_DEFAULT_FORMAT_TEXT 0  // 1: start in the paper's text format
#endif
#ifndef SKINLOC_GAIN
#define SKINLOC_GAIN 8
#endif
// The paper's skin: 8 TX x 8 RX on the first lines. Edit, or send "l ..." at run time.
#ifndef SKINLOC_TX_LINES
#define SKINLOC_TX_LINES 8
#endif
#ifndef SKINLOC_RX_LINES
#define SKINLOC_RX_LINES 8
#endif

static const char VERSION[] = "skinloc_muca 1.0.0";

Muca muca;
static bool text_format = SKINLOC_DEFAULT_FORMAT_TEXT;
static uint8_t gain = SKINLOC_GAIN;
static bool tx_used[SKW_MAX_TX];
static bool rx_used[SKW_MAX_RX];
static uint16_t counter = 0;
static char cmd[64];
static uint8_t cmd_len = 0;

static void serial_write(const uint8_t *data, size_t len, void *ctx) {
  (void)ctx;
  Serial.write(data, len);
}

static void start_controller() {
  muca.init(false);
  muca.useRawData(true);  // raw counts; the interrupt does not work in this mode
  muca.selectLines(rx_used, tx_used);
  delay(50);
  muca.setGain(gain);
}

static uint8_t count_ones(const bool *lines, uint8_t n) {
  uint8_t k = 0;
  for (uint8_t i = 0; i < n; i++) k += lines[i] ? 1 : 0;
  return k;
}

static void report_version() {
  Serial.print(VERSION);
  Serial.print(" grid ");
  Serial.print(muca.num_TX);
  Serial.print('x');
  Serial.print(muca.num_RX);
  Serial.print(" format ");
  Serial.print(text_format ? "text" : "binary");
  Serial.print(" gain ");
  Serial.println(gain);
}

static bool parse_mask(const char *s, bool *lines, uint8_t n) {
  uint8_t i = 0;
  for (; s[i] && s[i] != ' '; i++) {
    if (i >= n || (s[i] != '0' && s[i] != '1')) return false;
  }
  for (uint8_t k = 0; k < n; k++) lines[k] = k < i && s[k] == '1';
  return count_ones(lines, n) > 0;
}

static void handle_command(char *line) {
  switch (line[0]) {
    case 'v':
      report_version();
      break;
    case 'f':
      if (strncmp(line, "f text", 6) == 0) {
        text_format = true;
        Serial.println("ok format text");
      } else if (strncmp(line, "f binary", 8) == 0) {
        text_format = false;
        Serial.println("ok format binary");
      } else {
        Serial.println("error usage: f text|binary");
      }
      break;
    case 'g': {
      long g = atol(line + 1);
      if (g < 0 || g > 255 || line[1] != ' ') {
        Serial.println("error gain must be 0-255");
      } else {
        gain = (uint8_t)g;
        muca.setGain(gain);
        Serial.print("ok gain ");
        Serial.println(gain);
      }
      break;
    }
    case 'l': {
      bool tx[SKW_MAX_TX], rx[SKW_MAX_RX];
      char *rx_text = strchr(line + 2, ' ');
      if (line[1] != ' ' || rx_text == NULL || !parse_mask(line + 2, tx, SKW_MAX_TX) ||
          !parse_mask(rx_text + 1, rx, SKW_MAX_RX)) {
        Serial.println("error usage: l TXMASK RXMASK, e.g. l 11111111 11111111");
        break;
      }
      memcpy(tx_used, tx, sizeof tx);
      memcpy(rx_used, rx, sizeof rx);
      muca.selectLines(rx_used, tx_used);
      Serial.print("ok lines ");
      Serial.print(count_ones(tx_used, SKW_MAX_TX));
      Serial.print('x');
      Serial.println(count_ones(rx_used, SKW_MAX_RX));
      break;
    }
    case 'c':
      start_controller();
      Serial.println("ok recalibrated");
      break;
    case '?':
      Serial.println("commands: v | f text|binary | g N | l TXMASK RXMASK | c | ?");
      break;
    default:
      Serial.println("error unknown command; send ? for the list");
  }
}

static void poll_commands() {
  while (Serial.available() > 0) {
    char ch = (char)Serial.read();
    if (ch == '\r') continue;
    if (ch == '\n') {
      cmd[cmd_len] = '\0';
      if (cmd_len > 0) handle_command(cmd);
      cmd_len = 0;
    } else if (cmd_len < sizeof(cmd) - 1) {
      cmd[cmd_len++] = ch;
    } else {
      cmd_len = 0;  // overlong: drop it
    }
  }
}

static void send_frame() {
  const uint8_t n_tx = muca.num_TX, n_rx = muca.num_RX;
  const uint16_t n = (uint16_t)n_tx * n_rx;
  if (text_format) {  // the paper's format: "v0,v1,...,v(n-1)\r\n"
    for (uint16_t i = 0; i < n; i++) {
      Serial.print(muca.grid[i]);
      if (i != n - 1) Serial.print(',');
    }
    Serial.println();
  } else {
    skw_encoder enc;
    if (skw_begin(&enc, serial_write, NULL, n_tx, n_rx, counter) == 0) {
      for (uint16_t i = 0; i < n; i++) skw_put_value(&enc, (uint16_t)muca.grid[i]);
      skw_end(&enc);
    }
  }
  counter++;
}

void setup() {
  Serial.begin(SKINLOC_BAUD);
  for (uint8_t i = 0; i < SKW_MAX_TX; i++) tx_used[i] = i < SKINLOC_TX_LINES;
  for (uint8_t i = 0; i < SKW_MAX_RX; i++) rx_used[i] = i < SKINLOC_RX_LINES;
  start_controller();
  Serial.print(VERSION);
  Serial.println(" ready");
}

void loop() {
  poll_commands();
  if (muca.updated()) send_frame();
}
