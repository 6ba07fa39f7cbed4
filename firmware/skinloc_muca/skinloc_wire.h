/*
 * skinloc_wire.h - encoder of the skinloc binary wire format (docs/protocol.md), version 1.
 *
 * One small header shared by the Arduino sketch (skinloc_muca.ino) and the host-side test
 * (tests/host_c/wire_test.c), which checks it byte for byte against skinloc.framing in Python.
 *
 * Frame, all little-endian:
 *
 *   A5 5A | version (1) | n_tx | n_rx | counter u16 | n_tx*n_rx values u16 | CRC-32 u32
 *
 * The CRC-32 is the IEEE 802.3 / zlib one (reflected polynomial 0xEDB88320, initial value and
 * final XOR 0xFFFFFFFF) over version .. last value. It is computed with a 16-entry nibble table
 * (64 bytes) so it fits an AVR: about 2 ms for the full 21 x 12 grid on a 16 MHz Uno.
 *
 * The streaming API never needs the frame in RAM: skw_begin, skw_put_value for every value in
 * TX-major order, skw_end; each emits bytes through a callback (Serial.write on the board).
 * skw_encode writes a whole frame into a buffer (the host test uses it).
 */
#ifndef SKINLOC_WIRE_H
#define SKINLOC_WIRE_H

#include <stddef.h>
#include <stdint.h>

#define SKW_SYNC0 0xA5u
#define SKW_SYNC1 0x5Au
#define SKW_VERSION 1u
#define SKW_MAX_TX 21u
#define SKW_MAX_RX 12u
#define SKW_HEADER_SIZE 7u
#define SKW_CRC_SIZE 4u
#define SKW_FRAME_SIZE(n_tx, n_rx) (SKW_HEADER_SIZE + 2u * (size_t)(n_tx) * (n_rx) + SKW_CRC_SIZE)

#ifdef __cplusplus
extern "C" {
#endif

typedef void (*skw_write_fn)(const uint8_t *data, size_t len, void *ctx);

typedef struct {
    uint32_t crc;
    skw_write_fn write;
    void *ctx;
} skw_encoder;

#if defined(__AVR__)
#include <avr/pgmspace.h>
#define SKW_TABLE_READ(i) pgm_read_dword(&skw_crc_nibbles[(i)])
#define SKW_PROGMEM PROGMEM
#else
#define SKW_TABLE_READ(i) (skw_crc_nibbles[(i)])
#define SKW_PROGMEM
#endif

static const uint32_t skw_crc_nibbles[16] SKW_PROGMEM = {
    0x00000000UL, 0x1DB71064UL, 0x3B6E20C8UL, 0x26D930ACUL, 0x76DC4190UL, 0x6B6B51F4UL,
    0x4DB26158UL, 0x5005713CUL, 0xEDB88320UL, 0xF00F9344UL, 0xD6D6A3E8UL, 0xCB61B38CUL,
    0x9B64C2B0UL, 0x86D3D2D4UL, 0xA00AE278UL, 0xBDBDF21CUL,
};

/* Feed one byte into a running CRC-32 (start from 0xFFFFFFFF, finish with ~crc). */
static inline uint32_t skw_crc32_byte(uint32_t crc, uint8_t b) {
    crc ^= b;
    crc = (crc >> 4) ^ SKW_TABLE_READ(crc & 0x0Fu);
    crc = (crc >> 4) ^ SKW_TABLE_READ(crc & 0x0Fu);
    return crc;
}

/* CRC-32 (zlib) of a buffer; skw_crc32("123456789", 9) == 0xCBF43926. */
static inline uint32_t skw_crc32(const uint8_t *data, size_t len) {
    uint32_t crc = 0xFFFFFFFFUL;
    for (size_t i = 0; i < len; i++) crc = skw_crc32_byte(crc, data[i]);
    return ~crc;
}

static inline void skw_emit(skw_encoder *enc, const uint8_t *data, size_t len, int crc) {
    if (crc)
        for (size_t i = 0; i < len; i++) enc->crc = skw_crc32_byte(enc->crc, data[i]);
    enc->write(data, len, enc->ctx);
}

/* Start a frame; returns 0, or -1 when the grid is outside 1-21 x 1-12. */
static inline int skw_begin(skw_encoder *enc, skw_write_fn write, void *ctx, uint8_t n_tx,
                            uint8_t n_rx, uint16_t counter) {
    if (n_tx < 1 || n_tx > SKW_MAX_TX || n_rx < 1 || n_rx > SKW_MAX_RX) return -1;
    enc->crc = 0xFFFFFFFFUL;
    enc->write = write;
    enc->ctx = ctx;
    const uint8_t sync[2] = {SKW_SYNC0, SKW_SYNC1};
    const uint8_t head[5] = {SKW_VERSION, n_tx, n_rx, (uint8_t)(counter & 0xFFu),
                             (uint8_t)(counter >> 8)};
    skw_emit(enc, sync, 2, 0);
    skw_emit(enc, head, 5, 1);
    return 0;
}

/* Append one value (raw count); call exactly n_tx * n_rx times, TX-major. */
static inline void skw_put_value(skw_encoder *enc, uint16_t value) {
    const uint8_t le[2] = {(uint8_t)(value & 0xFFu), (uint8_t)(value >> 8)};
    skw_emit(enc, le, 2, 1);
}

/* Finish the frame: append the CRC. */
static inline void skw_end(skw_encoder *enc) {
    uint32_t crc = ~enc->crc;
    const uint8_t le[4] = {(uint8_t)crc, (uint8_t)(crc >> 8), (uint8_t)(crc >> 16),
                           (uint8_t)(crc >> 24)};
    skw_emit(enc, le, 4, 0);
}

typedef struct {
    uint8_t *buf;
    size_t cap;
    size_t len;
} skw_buffer;

static inline void skw_buffer_write(const uint8_t *data, size_t len, void *ctx) {
    skw_buffer *b = (skw_buffer *)ctx;
    for (size_t i = 0; i < len && b->len < b->cap; i++) b->buf[b->len++] = data[i];
}

/* Encode a whole frame into out[cap]; returns its size, or 0 if the grid is bad or cap small. */
static inline size_t skw_encode(uint8_t *out, size_t cap, uint16_t counter, uint8_t n_tx,
                                uint8_t n_rx, const uint16_t *values) {
    if (n_tx < 1 || n_tx > SKW_MAX_TX || n_rx < 1 || n_rx > SKW_MAX_RX) return 0;
    size_t size = SKW_FRAME_SIZE(n_tx, n_rx);
    if (cap < size) return 0;
    skw_buffer b = {out, cap, 0};
    skw_encoder enc;
    skw_begin(&enc, skw_buffer_write, &b, n_tx, n_rx, counter);
    for (size_t i = 0; i < (size_t)n_tx * n_rx; i++) skw_put_value(&enc, values[i]);
    skw_end(&enc);
    return b.len;
}

#ifdef __cplusplus
}
#endif

#endif /* SKINLOC_WIRE_H */
