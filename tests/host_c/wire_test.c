/*
 * Host-side test of firmware/skinloc_muca/skinloc_wire.h, compiled with gcc by
 * tests/test_framing.py. Reads cases from stdin, one per line:
 *
 *   n_tx n_rx counter v0 v1 ... v(n-1)
 *
 * and writes each encoded frame as one line of lowercase hex on stdout. A line "crc" prints the
 * CRC-32 of "123456789" instead (must be cbf43926).
 */
#include <stdio.h>
#include <string.h>

#include "skinloc_wire.h"

int main(void) {
    char word[16];
    static uint16_t values[SKW_MAX_TX * SKW_MAX_RX];
    static uint8_t out[SKW_FRAME_SIZE(SKW_MAX_TX, SKW_MAX_RX)];
    while (scanf("%15s", word) == 1) {
        if (strcmp(word, "crc") == 0) {
            printf("%08lx\n", (unsigned long)skw_crc32((const uint8_t *)"123456789", 9));
            continue;
        }
        unsigned n_tx = 0, n_rx = 0, counter = 0;
        if (sscanf(word, "%u", &n_tx) != 1 || scanf("%u %u", &n_rx, &counter) != 2) return 2;
        unsigned n = n_tx * n_rx;
        if (n > SKW_MAX_TX * SKW_MAX_RX) n = SKW_MAX_TX * SKW_MAX_RX;
        for (unsigned i = 0; i < n; i++) {
            unsigned v;
            if (scanf("%u", &v) != 1) return 3;
            values[i] = (uint16_t)v;
        }
        size_t len = skw_encode(out, sizeof out, (uint16_t)counter, (uint8_t)n_tx,
                                (uint8_t)n_rx, values);
        for (size_t i = 0; i < len; i++) printf("%02x", out[i]);
        printf("\n");
    }
    return 0;
}
