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
 * final XOR 0xFFFFFFFF) over version .. last value. It is computed a byte at a time with a
 * 256-entry table (1 KB, in flash on an AVR): a 16-entry nibble table took 9 us a byte on a
 * 16 MHz Uno (measured in the emulator), slower than the 1 Mbaud link itself.
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
#define SKW_TABLE_READ(i) pgm_read_dword(&skw_crc_table[(i)])
#define SKW_PROGMEM PROGMEM
#else
#define SKW_TABLE_READ(i) (skw_crc_table[(i)])
#define SKW_PROGMEM
#endif

/* skw_crc_table[i]: the CRC-32 register after shifting byte i through it (reflected 0xEDB88320). */
static const uint32_t skw_crc_table[256] SKW_PROGMEM = {
    0x00000000UL, 0x77073096UL, 0xEE0E612CUL, 0x990951BAUL, 0x076DC419UL, 0x706AF48FUL,
    0xE963A535UL, 0x9E6495A3UL, 0x0EDB8832UL, 0x79DCB8A4UL, 0xE0D5E91EUL, 0x97D2D988UL,
    0x09B64C2BUL, 0x7EB17CBDUL, 0xE7B82D07UL, 0x90BF1D91UL, 0x1DB71064UL, 0x6AB020F2UL,
    0xF3B97148UL, 0x84BE41DEUL, 0x1ADAD47DUL, 0x6DDDE4EBUL, 0xF4D4B551UL, 0x83D385C7UL,
    0x136C9856UL, 0x646BA8C0UL, 0xFD62F97AUL, 0x8A65C9ECUL, 0x14015C4FUL, 0x63066CD9UL,
    0xFA0F3D63UL, 0x8D080DF5UL, 0x3B6E20C8UL, 0x4C69105EUL, 0xD56041E4UL, 0xA2677172UL,
    0x3C03E4D1UL, 0x4B04D447UL, 0xD20D85FDUL, 0xA50AB56BUL, 0x35B5A8FAUL, 0x42B2986CUL,
    0xDBBBC9D6UL, 0xACBCF940UL, 0x32D86CE3UL, 0x45DF5C75UL, 0xDCD60DCFUL, 0xABD13D59UL,
    0x26D930ACUL, 0x51DE003AUL, 0xC8D75180UL, 0xBFD06116UL, 0x21B4F4B5UL, 0x56B3C423UL,
    0xCFBA9599UL, 0xB8BDA50FUL, 0x2802B89EUL, 0x5F058808UL, 0xC60CD9B2UL, 0xB10BE924UL,
    0x2F6F7C87UL, 0x58684C11UL, 0xC1611DABUL, 0xB6662D3DUL, 0x76DC4190UL, 0x01DB7106UL,
    0x98D220BCUL, 0xEFD5102AUL, 0x71B18589UL, 0x06B6B51FUL, 0x9FBFE4A5UL, 0xE8B8D433UL,
    0x7807C9A2UL, 0x0F00F934UL, 0x9609A88EUL, 0xE10E9818UL, 0x7F6A0DBBUL, 0x086D3D2DUL,
    0x91646C97UL, 0xE6635C01UL, 0x6B6B51F4UL, 0x1C6C6162UL, 0x856530D8UL, 0xF262004EUL,
    0x6C0695EDUL, 0x1B01A57BUL, 0x8208F4C1UL, 0xF50FC457UL, 0x65B0D9C6UL, 0x12B7E950UL,
    0x8BBEB8EAUL, 0xFCB9887CUL, 0x62DD1DDFUL, 0x15DA2D49UL, 0x8CD37CF3UL, 0xFBD44C65UL,
    0x4DB26158UL, 0x3AB551CEUL, 0xA3BC0074UL, 0xD4BB30E2UL, 0x4ADFA541UL, 0x3DD895D7UL,
    0xA4D1C46DUL, 0xD3D6F4FBUL, 0x4369E96AUL, 0x346ED9FCUL, 0xAD678846UL, 0xDA60B8D0UL,
    0x44042D73UL, 0x33031DE5UL, 0xAA0A4C5FUL, 0xDD0D7CC9UL, 0x5005713CUL, 0x270241AAUL,
    0xBE0B1010UL, 0xC90C2086UL, 0x5768B525UL, 0x206F85B3UL, 0xB966D409UL, 0xCE61E49FUL,
    0x5EDEF90EUL, 0x29D9C998UL, 0xB0D09822UL, 0xC7D7A8B4UL, 0x59B33D17UL, 0x2EB40D81UL,
    0xB7BD5C3BUL, 0xC0BA6CADUL, 0xEDB88320UL, 0x9ABFB3B6UL, 0x03B6E20CUL, 0x74B1D29AUL,
    0xEAD54739UL, 0x9DD277AFUL, 0x04DB2615UL, 0x73DC1683UL, 0xE3630B12UL, 0x94643B84UL,
    0x0D6D6A3EUL, 0x7A6A5AA8UL, 0xE40ECF0BUL, 0x9309FF9DUL, 0x0A00AE27UL, 0x7D079EB1UL,
    0xF00F9344UL, 0x8708A3D2UL, 0x1E01F268UL, 0x6906C2FEUL, 0xF762575DUL, 0x806567CBUL,
    0x196C3671UL, 0x6E6B06E7UL, 0xFED41B76UL, 0x89D32BE0UL, 0x10DA7A5AUL, 0x67DD4ACCUL,
    0xF9B9DF6FUL, 0x8EBEEFF9UL, 0x17B7BE43UL, 0x60B08ED5UL, 0xD6D6A3E8UL, 0xA1D1937EUL,
    0x38D8C2C4UL, 0x4FDFF252UL, 0xD1BB67F1UL, 0xA6BC5767UL, 0x3FB506DDUL, 0x48B2364BUL,
    0xD80D2BDAUL, 0xAF0A1B4CUL, 0x36034AF6UL, 0x41047A60UL, 0xDF60EFC3UL, 0xA867DF55UL,
    0x316E8EEFUL, 0x4669BE79UL, 0xCB61B38CUL, 0xBC66831AUL, 0x256FD2A0UL, 0x5268E236UL,
    0xCC0C7795UL, 0xBB0B4703UL, 0x220216B9UL, 0x5505262FUL, 0xC5BA3BBEUL, 0xB2BD0B28UL,
    0x2BB45A92UL, 0x5CB36A04UL, 0xC2D7FFA7UL, 0xB5D0CF31UL, 0x2CD99E8BUL, 0x5BDEAE1DUL,
    0x9B64C2B0UL, 0xEC63F226UL, 0x756AA39CUL, 0x026D930AUL, 0x9C0906A9UL, 0xEB0E363FUL,
    0x72076785UL, 0x05005713UL, 0x95BF4A82UL, 0xE2B87A14UL, 0x7BB12BAEUL, 0x0CB61B38UL,
    0x92D28E9BUL, 0xE5D5BE0DUL, 0x7CDCEFB7UL, 0x0BDBDF21UL, 0x86D3D2D4UL, 0xF1D4E242UL,
    0x68DDB3F8UL, 0x1FDA836EUL, 0x81BE16CDUL, 0xF6B9265BUL, 0x6FB077E1UL, 0x18B74777UL,
    0x88085AE6UL, 0xFF0F6A70UL, 0x66063BCAUL, 0x11010B5CUL, 0x8F659EFFUL, 0xF862AE69UL,
    0x616BFFD3UL, 0x166CCF45UL, 0xA00AE278UL, 0xD70DD2EEUL, 0x4E048354UL, 0x3903B3C2UL,
    0xA7672661UL, 0xD06016F7UL, 0x4969474DUL, 0x3E6E77DBUL, 0xAED16A4AUL, 0xD9D65ADCUL,
    0x40DF0B66UL, 0x37D83BF0UL, 0xA9BCAE53UL, 0xDEBB9EC5UL, 0x47B2CF7FUL, 0x30B5FFE9UL,
    0xBDBDF21CUL, 0xCABAC28AUL, 0x53B39330UL, 0x24B4A3A6UL, 0xBAD03605UL, 0xCDD70693UL,
    0x54DE5729UL, 0x23D967BFUL, 0xB3667A2EUL, 0xC4614AB8UL, 0x5D681B02UL, 0x2A6F2B94UL,
    0xB40BBE37UL, 0xC30C8EA1UL, 0x5A05DF1BUL, 0x2D02EF8DUL,
};

/* Feed one byte into a running CRC-32 (start from 0xFFFFFFFF, finish with ~crc). */
static inline uint32_t skw_crc32_byte(uint32_t crc, uint8_t b) {
    return (crc >> 8) ^ SKW_TABLE_READ((uint8_t)(crc ^ b));
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

/* Finish a frame that went wrong after it started (the controller stopped answering): pad it
 * with zeros to its announced size and append a CRC that does not match, so that every decoder
 * drops it; call instead of the remaining skw_put_value and skw_end. */
static inline void skw_end_bad(skw_encoder *enc, uint16_t missing_values) {
    for (uint16_t i = 0; i < missing_values; i++) skw_put_value(enc, 0);
    uint32_t crc = ~enc->crc ^ 0x5A5A5A5AUL; /* anything but the right CRC */
    const uint8_t le[4] = {(uint8_t)crc, (uint8_t)(crc >> 8), (uint8_t)(crc >> 16),
                           (uint8_t)(crc >> 24)};
    skw_emit(enc, le, 4, 0);
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
