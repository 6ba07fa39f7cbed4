/*
 * skinloc_muca.ino - stream raw mutual-capacitance frames from a Muca board to skinloc.
 *
 * Board: an Arduino (Uno, Nano, Leonardo, Zero...) wired to a Muca breakout (FocalTech FT5x06,
 * up to 21 TX x 12 RX) over I2C; see firmware/README.md for wiring, building and flashing.
 * Needs the Arduino core and its Wire library only: the controller is driven by ft5x06.h.
 *
 * Output: every frame the controller produces, either in skinloc's binary format
 * (docs/protocol.md, the default) or in the paper's text format (one line of comma-separated
 * counts, TX-major). Input: one command per line (newline-terminated):
 *
 *   v                 version, grid, format, gain and controller state, e.g.
 *                     "skinloc_muca 1.1.0 grid 8x8 format binary gain 8 controller ok"
 *   f text|binary     switch the output format
 *   g N               set the analog gain, 1-31 (the controller's range)
 *   l TXMASK RXMASK   select lines, e.g. "l 111111110000000000000 111111110000" (1 = used);
 *                     the grid becomes the number of ones; masks shorter than 21 / 12 mean
 *                     that the remaining lines are unused
 *   c                 recalibrate: look for the controller again and re-initialise it
 *   ?                 list the commands
 *
 * The gain and the lines are kept in EEPROM: they survive the reset that opening the port
 * causes on an Uno, so a host can set them once and then open the port to stream.
 *
 * Replies are single text lines ("ok ...", "error ..."); the host skips them in both formats.
 * Memory: no heap; the only frame buffer is one TX line (12 values, the most RX lines there
 * are), whatever the lines selected; strings in flash.
 */
#include <Arduino.h>
#include <Wire.h>
#include <avr/eeprom.h>
#include <avr/pgmspace.h>

#include "ft5x06.h"
#include "skinloc_wire.h"

#ifndef SKINLOC_BAUD
#define SKINLOC_BAUD 1000000UL  // the link carries the whole 21 x 12 grid at 194 frames/s
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
#ifndef SKINLOC_I2C_HZ
#define SKINLOC_I2C_HZ 400000UL
#endif

#if SKINLOC_GAIN < FT_GAIN_MIN || SKINLOC_GAIN > FT_GAIN_MAX
#error "SKINLOC_GAIN must be 1-31"
#endif
#if SKINLOC_TX_LINES < 1 || SKINLOC_TX_LINES > 21 || SKINLOC_RX_LINES < 1 || SKINLOC_RX_LINES > 12
#error "SKINLOC_TX_LINES must be 1-21 and SKINLOC_RX_LINES 1-12"
#endif

#define SKINLOC_VERSION "skinloc_muca 1.1.0"
#define RETRY_MS 1000  // how often a missing or silent controller is looked for again

static uint16_t row[SKW_MAX_RX];  // the one frame buffer: a TX line (the frame streams out)
static uint32_t tx_mask;          // bit t: TX line t is read
static uint16_t rx_mask;          // bit r: RX line r is kept
static uint8_t n_tx, n_rx;
static uint8_t gain = SKINLOC_GAIN;
static bool text_format = SKINLOC_DEFAULT_FORMAT_TEXT;
static ft_status controller = FT_OK;  // so that a missing one is announced at start
static unsigned long last_retry_ms;
static uint16_t counter;
static char cmd[48];  // the longest command, "l" + 21 + 12 mask digits, is 36 characters
static uint8_t cmd_len;
static bool cmd_overlong;

// The settings kept in EEPROM, with a check that they were written by this sketch.
struct settings {
  uint8_t magic;  // SETTINGS_MAGIC
  uint8_t gain;
  uint32_t tx_mask;
  uint16_t rx_mask;
  uint8_t check;  // sum of the bytes above, plus 1
};
#define SETTINGS_MAGIC 0x5C
static settings EEMEM saved;

static uint8_t settings_check(const settings *s) {
  const uint8_t *b = (const uint8_t *)s;
  uint8_t sum = 1;
  for (uint8_t i = 0; i < offsetof(settings, check); i++) sum += b[i];
  return sum;
}

static void serial_write(const uint8_t *data, size_t len, void *ctx) {
  (void)ctx;
  Serial.write(data, len);
}

static uint8_t count_bits(uint32_t bits) {
  uint8_t k = 0;
  for (; bits; bits &= bits - 1) k++;
  return k;
}

static void say_controller_trouble() {
  if (controller == FT_MISSING)
    Serial.println(F("error no controller at I2C 0x38: check SDA, SCL, VCC and GND"));
  else
    Serial.println(F("error controller answers but does not scan: check its supply, send c"));
}

// Set the state; a change for the worse is announced once (a chatter line the host skips).
static void set_controller(ft_status s) {
  if (s != FT_OK && s != controller) {
    controller = s;
    say_controller_trouble();
  }
  controller = s;
  last_retry_ms = millis();
}

static void start_controller() { set_controller(ft_begin(gain)); }

static void report_version() {
  Serial.print(F(SKINLOC_VERSION " grid "));
  Serial.print(n_tx);
  Serial.print('x');
  Serial.print(n_rx);
  Serial.print(text_format ? F(" format text gain ") : F(" format binary gain "));
  Serial.print(gain);
  Serial.print(F(" controller "));
  Serial.println(controller == FT_OK        ? F("ok")
                 : controller == FT_MISSING ? F("missing")
                                            : F("silent"));
}

// Parse a mask of '0'/'1' (at most n digits, then a space or the end) into bits.
static const char *parse_mask(const char *s, uint8_t n, uint32_t *bits) {
  uint32_t b = 0;
  uint8_t i = 0;
  for (; *s && *s != ' '; s++, i++) {
    if (i >= n || (*s != '0' && *s != '1')) return NULL;
    if (*s == '1') b |= 1UL << i;
  }
  if (b == 0) return NULL;
  *bits = b;
  return s;
}

static void set_lines(uint32_t tx, uint16_t rx) {
  tx_mask = tx;
  rx_mask = rx;
  n_tx = count_bits(tx);
  n_rx = count_bits(rx);
}

static void save_settings() {
  settings s = {SETTINGS_MAGIC, gain, tx_mask, rx_mask, 0};
  s.check = settings_check(&s);
  eeprom_update_block(&s, &saved, sizeof s);  // writes only the bytes that changed
}

// The saved gain and lines, if they are valid; the build's defaults otherwise.
static void load_settings() {
  settings s;
  eeprom_read_block(&s, &saved, sizeof s);
  const bool ok = s.magic == SETTINGS_MAGIC && s.check == settings_check(&s) &&
                  s.gain >= FT_GAIN_MIN && s.gain <= FT_GAIN_MAX && s.tx_mask != 0 &&
                  s.tx_mask < (1UL << SKW_MAX_TX) && s.rx_mask != 0 &&
                  s.rx_mask < (1u << SKW_MAX_RX);
  if (ok) {
    gain = s.gain;
    set_lines(s.tx_mask, s.rx_mask);
  } else {
    gain = SKINLOC_GAIN;
    set_lines((1UL << SKINLOC_TX_LINES) - 1, (uint16_t)((1u << SKINLOC_RX_LINES) - 1));
  }
}

static void command_lines(const char *line) {
  uint32_t tx = 0, rx = 0;
  const char *rest = line[1] == ' ' ? parse_mask(line + 2, SKW_MAX_TX, &tx) : NULL;
  if (rest != NULL && *rest == ' ') rest = parse_mask(rest + 1, SKW_MAX_RX, &rx);
  else rest = NULL;
  if (rest == NULL || *rest != '\0') {
    Serial.println(F("error usage: l TXMASK RXMASK, e.g. l 11111111 11111111"));
    return;
  }
  set_lines(tx, (uint16_t)rx);
  save_settings();
  Serial.print(F("ok lines "));
  Serial.print(n_tx);
  Serial.print('x');
  Serial.println(n_rx);
}

static void command_gain(const char *line) {
  // "g N": digits only, 1-31.
  uint16_t g = 0;
  const char *s = line + 2;
  bool ok = line[1] == ' ' && *s != '\0';
  for (; ok && *s; s++) {
    ok = *s >= '0' && *s <= '9' && g < 100;
    g = (uint16_t)(g * 10 + (*s - '0'));
  }
  if (!ok || g < FT_GAIN_MIN || g > FT_GAIN_MAX) {
    Serial.println(F("error gain must be 1-31"));
    return;
  }
  gain = (uint8_t)g;
  save_settings();
  if (controller == FT_OK) set_controller(ft_set_gain(gain));
  Serial.print(F("ok gain "));
  Serial.println(gain);
}

static void handle_command(const char *line) {
  switch (line[0]) {
    case 'v':
      if (line[1] == '\0') {
        report_version();
        return;
      }
      break;
    case 'f':
      if (strcmp_P(line, PSTR("f text")) == 0) {
        text_format = true;
        Serial.println(F("ok format text"));
      } else if (strcmp_P(line, PSTR("f binary")) == 0) {
        text_format = false;
        Serial.println(F("ok format binary"));
      } else {
        Serial.println(F("error usage: f text|binary"));
      }
      return;
    case 'g':
      command_gain(line);
      return;
    case 'l':
      command_lines(line);
      return;
    case 'c':
      if (line[1] == '\0') {
        controller = FT_OK;  // so that the reply says what is wrong if it still is
        set_controller(ft_begin(gain));
        if (controller == FT_OK) Serial.println(F("ok recalibrated"));
        return;
      }
      break;
    case '?':
      if (line[1] == '\0') {
        Serial.println(F("commands: v | f text|binary | g N | l TXMASK RXMASK | c | ?"));
        return;
      }
      break;
  }
  Serial.println(F("error unknown command; send ? for the list"));
}

static void poll_commands() {
  while (Serial.available() > 0) {
    const char ch = (char)Serial.read();
    if (ch == '\r') continue;
    if (ch == '\n') {
      cmd[cmd_len] = '\0';
      if (cmd_overlong) Serial.println(F("error command too long; send ? for the list"));
      else if (cmd_len > 0) handle_command(cmd);
      cmd_len = 0;
      cmd_overlong = false;
    } else if (cmd_len < sizeof(cmd) - 1) {
      cmd[cmd_len++] = ch;
    } else {
      cmd_overlong = true;  // keep reading to the newline, then refuse the whole line
    }
  }
}

static void put_row(skw_encoder *enc, bool first_row) {
  for (uint8_t r = 0; r < n_rx; r++) {
    if (text_format) {  // the paper's format: "v0,v1,...,v(n-1)\r\n"
      if (!first_row || r) Serial.write(',');
      Serial.print(row[r]);
    } else {
      skw_put_value(enc, row[r]);
    }
  }
}

// One raw scan of the selected lines, sent as one frame. Each TX line goes out while the next
// is read (the UART sends from its buffer by interrupt): the link and the I2C bus overlap.
static void stream_frame() {
  ft_status s = ft_scan();
  if (s != FT_OK) {
    set_controller(s);
    return;
  }
  skw_encoder enc;
  if (!text_format) skw_begin(&enc, serial_write, NULL, n_tx, n_rx, counter);
  uint8_t done = 0;
  for (uint8_t tx = 0; tx < SKW_MAX_TX; tx++) {
    if (!(tx_mask & (1UL << tx))) continue;
    s = ft_read_tx(tx, rx_mask, row);
    if (s != FT_OK) break;
    put_row(&enc, done == 0);
    done++;
  }
  if (s == FT_OK) {
    if (text_format) Serial.println();
    else skw_end(&enc);
    counter++;
    return;
  }
  // The controller stopped answering mid-frame: send a frame every decoder drops (a short
  // text line; a binary frame with a bad CRC), and keep the counter (nothing was delivered).
  if (text_format) Serial.println();
  else skw_end_bad(&enc, (uint16_t)(n_tx - done) * n_rx);
  set_controller(s);
}

void setup() {
  Serial.begin(SKINLOC_BAUD);
  Wire.begin();
  Wire.setClock(SKINLOC_I2C_HZ);
  Wire.setWireTimeout(25000, true);  // a stuck bus must not hang the sketch
  load_settings();
  start_controller();
  if (controller == FT_OK) Serial.println(F(SKINLOC_VERSION " ready"));
}

void loop() {
  poll_commands();
  if (controller != FT_OK) {
    if (millis() - last_retry_ms >= RETRY_MS) start_controller();
    return;
  }
  stream_frame();
}
