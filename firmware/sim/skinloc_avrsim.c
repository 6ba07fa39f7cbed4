/*
 * skinloc_avrsim.c - the emulated skinloc board: the firmware's .elf running in simavr, an
 * emulated FT5x06 on the TWI bus, and the UART bridged to a pseudo-terminal.
 *
 *   skinloc_avrsim FIRMWARE.elf [options]
 *
 * prints "pty /dev/pts/N" on stdout; skinloc reads that port as it would a real board's
 * (`skinloc monitor --port /dev/pts/N`). SIGUSR1 prints one line of JSON with its counters;
 * on SIGINT/SIGTERM it stops and prints that line, then exits 0, or 3 when the AVR faulted
 * (an invalid memory access or opcode, or the stack ran into the data).
 *
 * The emulated controller answers at I2C address 0x38 with the register map of
 * firmware/skinloc_muca/ft5x06.h. Each raw scan (register 0x00 = 0xC0) takes --scan-us
 * emulated microseconds and latches one new 21 x 12 frame of raw counts, which comes from:
 *
 *   --feed-fd N   a socket: the harness sends "S" and reads 21 x 12 uint16 little-endian
 *                 counts, TX-major by the skin's TX line (skinloc's Python side serves its
 *                 simulated skin there). Host lines "touch X Y Z" and "lift" are a bench
 *                 finger, not board commands: they go to the socket as "T<line>\n" and not
 *                 to the AVR. A reset of the board is announced as "R".
 *   (default)     a built-in pattern that says where each value comes from:
 *                 value(tx, rx) = (scan & 0xFF) << 8 | (tx * 12 + rx).
 *
 * The UART bridge never drops a byte while a host holds the port open: when the host reads
 * slower than the firmware writes, the emulation waits (the AVR's clock stops). While no host
 * has the port open the bytes are dropped and counted, and a host opening the port resets
 * the AVR, as the DTR line of an Uno does (--no-reset-on-open to keep it running); who holds
 * the port comes from inotify's open and close events on the pty.
 *
 * Options: --controller ok|missing|silent, --scan-us N (default 1000), --speed X (emulated
 * seconds per wall second, default 1; 0 runs as fast as it can), --dead-rx R and --dead-tx T
 * (that line reads 0; repeatable), --seconds S (stop after S wall seconds), --trace-twi.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/inotify.h>
#include <sys/prctl.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_twi.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_io.h"
#include "sim_irq.h"
#include "sim_time.h"

#define N_TX 21
#define N_RX 12
#define FT_ADDR 0x38
#define OUT_CAP (1 << 16)
#define OUT_HIGH 4096 /* pause the AVR when this much waits for the host */
#define IN_CAP 4096

/* ------------------------------------------------------------------ state */
enum { CTRL_OK, CTRL_MISSING, CTRL_SILENT };

typedef struct {
    avr_irq_t *irq; /* our TWI_IRQ_INPUT/OUTPUT pair */
    avr_t *avr;
    int mode;       /* how it behaves: CTRL_* */
    uint8_t regs[256];
    uint16_t raw[N_TX][N_RX]; /* the latched frame, by the skin's TX line */
    int selected, reading, index;
    uint8_t ptr;
    int scanning;
    uint32_t scan_us;
    avr_cycle_count_t tx_selected_at;
    int tx_settling; /* a TX line was selected: the next transfer must wait 50 us */
    /* counters */
    uint64_t scans, raw_reads, early_reads, bad_tx, reads_while_scanning, gain_writes;
    uint64_t naks;
    uint64_t bus_bytes; /* bytes on the bus (addresses and data), for the 400 kHz estimate */
    int gain;
} ft5x06_t;

static struct {
    avr_t *avr;
    ft5x06_t ft;
    int master; /* pty master */
    char slave_name[64];
    int host;   /* a host holds the port open */
    int inotify; /* open/close events of the pty's slave: who holds the port */
    int n_open;  /* how many hold it open now */
    int reset_on_open;
    uint8_t out[OUT_CAP];
    size_t out_head, out_len;
    uint8_t in[IN_CAP];
    size_t in_len;
    int xon;
    /* host line snooping: "touch ..." / "lift" go to the feed, not the AVR */
    char line[128];
    size_t line_len;
    int line_mode; /* 0: at a line start or holding a possible finger line; 1: passing */
    int feed_fd;
    uint32_t dead_rx, dead_tx;
    double speed;
    double seconds;
    int trace_twi;
    uint16_t data_end; /* first byte above .data/.bss/.noinit: the stack must stay above */
    uint16_t min_sp;
    uint64_t bytes_out, bytes_in, bytes_dropped, host_opens, resets, finger_lines;
    uint64_t out_stalls;
    avr_cycle_count_t paced_from; /* pacing: emulated cycle and wall time it started from */
    double paced_start;
    const char *fault;
} S;

static volatile sig_atomic_t stop_requested, stats_requested;
static void on_usr1(int sig) {
    (void)sig;
    stats_requested = 1;
}
static void on_signal(int sig) {
    (void)sig;
    stop_requested = 1;
}

static double now_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void die(const char *what) {
    fprintf(stderr, "skinloc_avrsim: %s: %s\n", what, strerror(errno));
    exit(2);
}

/* ------------------------------------------------------------------ the raw values */
static int read_full(int fd, void *buf, size_t n) {
    uint8_t *p = buf;
    while (n) {
        ssize_t k = read(fd, p, n);
        if (k < 0 && errno == EINTR) continue;
        if (k <= 0) return -1;
        p += k;
        n -= (size_t)k;
    }
    return 0;
}

static int write_full(int fd, const void *buf, size_t n) {
    const uint8_t *p = buf;
    while (n) {
        ssize_t k = write(fd, p, n);
        if (k < 0 && errno == EINTR) continue;
        if (k <= 0) return -1;
        p += k;
        n -= (size_t)k;
    }
    return 0;
}

static void latch_frame(ft5x06_t *ft) {
    if (S.feed_fd >= 0) {
        uint8_t buf[N_TX * N_RX * 2];
        if (write_full(S.feed_fd, "S", 1) != 0 || read_full(S.feed_fd, buf, sizeof buf) != 0) {
            fprintf(stderr, "skinloc_avrsim: the value feed closed; stopping\n");
            stop_requested = 1;
            return;
        }
        for (int t = 0; t < N_TX; t++)
            for (int r = 0; r < N_RX; r++) {
                int k = 2 * (t * N_RX + r);
                ft->raw[t][r] = (uint16_t)(buf[k] | buf[k + 1] << 8);
            }
    } else {
        for (int t = 0; t < N_TX; t++)
            for (int r = 0; r < N_RX; r++)
                ft->raw[t][r] = (uint16_t)((ft->scans & 0xFF) << 8 | (t * N_RX + r));
    }
    for (int t = 0; t < N_TX; t++)
        for (int r = 0; r < N_RX; r++)
            if ((S.dead_tx >> t & 1) || (S.dead_rx >> r & 1)) ft->raw[t][r] = 0;
    ft->scans++;
}

/* ------------------------------------------------------------------ the FT5x06 */
static avr_cycle_count_t scan_done(avr_t *avr, avr_cycle_count_t when, void *param) {
    (void)avr;
    (void)when;
    ft5x06_t *ft = param;
    if (ft->scanning) {
        latch_frame(ft);
        ft->scanning = 0;
        ft->regs[0x00] &= 0x7F;
    }
    return 0;
}

static void ft_write_reg(ft5x06_t *ft, uint8_t reg, uint8_t v) {
    if (reg == 0x00) {
        ft->regs[0] = v;
        if (v == 0xC0 && ft->mode == CTRL_OK && !ft->scanning) {
            ft->scanning = 1;
            avr_cycle_timer_register_usec(ft->avr, ft->scan_us, scan_done, ft);
        }
        return;
    }
    if (reg == 0x01) {
        if (v >= N_TX) ft->bad_tx++;
        ft->tx_selected_at = ft->avr->cycle;
        ft->tx_settling = 1;
    }
    if (reg == 0x07) {
        ft->gain_writes++;
        ft->gain = v;
    }
    ft->regs[reg] = v;
}

static uint8_t ft_read_reg(ft5x06_t *ft, uint8_t reg) {
    if (reg >= 0x10 && reg < 0x10 + 2 * N_RX) {
        uint8_t sel = ft->regs[0x01];
        int tx = N_TX - 1 - (sel < N_TX ? sel : 0); /* the controller counts TX in reverse */
        int rx = (reg - 0x10) / 2;
        if (reg == 0x10) {
            ft->raw_reads++;
            if (ft->scanning) ft->reads_while_scanning++;
        }
        uint16_t v = ft->raw[tx][rx];
        return (reg & 1) ? (uint8_t)(v & 0xFF) : (uint8_t)(v >> 8); /* big-endian */
    }
    return ft->regs[reg];
}

static void ft_twi_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    ft5x06_t *ft = param;
    avr_twi_msg_irq_t v;
    v.u.v = value;
    if (S.trace_twi)
        fprintf(stderr, "%.1f us twi msg %02x addr %02x data %02x\n", ft->avr->cycle / 16.0,
                v.u.twi.msg, v.u.twi.addr, v.u.twi.data);
    if (v.u.twi.msg & (TWI_COND_START | TWI_COND_WRITE | TWI_COND_READ)) ft->bus_bytes++;
    if (v.u.twi.msg & TWI_COND_STOP) {
        ft->selected = 0;
    }
    if (v.u.twi.msg & TWI_COND_START) {
        ft->selected = 0;
        ft->index = 0;
        if ((v.u.twi.addr >> 1) == FT_ADDR) {
            if (ft->mode == CTRL_MISSING) {
                ft->naks++;
                return;
            }
            ft->selected = 1;
            ft->reading = v.u.twi.addr & 1;
            /* the firmware must let a selected TX line settle 50 us before reading it */
            if (ft->tx_settling &&
                ft->avr->cycle - ft->tx_selected_at < avr_usec_to_cycles(ft->avr, 50))
                ft->early_reads++;
            ft->tx_settling = 0;
            avr_raise_irq(ft->irq + TWI_IRQ_INPUT, avr_twi_irq_msg(TWI_COND_ACK, v.u.twi.addr, 1));
        }
    }
    if (!ft->selected) return;
    if (v.u.twi.msg & TWI_COND_WRITE) {
        avr_raise_irq(ft->irq + TWI_IRQ_INPUT, avr_twi_irq_msg(TWI_COND_ACK, FT_ADDR << 1, 1));
        if (ft->index == 0)
            ft->ptr = v.u.twi.data;
        else
            ft_write_reg(ft, ft->ptr++, v.u.twi.data);
        ft->index++;
    }
    if (v.u.twi.msg & TWI_COND_READ) {
        uint8_t data = ft_read_reg(ft, ft->ptr++);
        avr_raise_irq(ft->irq + TWI_IRQ_INPUT,
                      avr_twi_irq_msg(TWI_COND_READ, FT_ADDR << 1 | 1, data));
    }
}

static const char *ft_irq_names[2] = {
    [TWI_IRQ_INPUT] = "8>ft5x06.out",
    [TWI_IRQ_OUTPUT] = "32<ft5x06.in",
};

static void ft_init(avr_t *avr, ft5x06_t *ft) {
    ft->avr = avr;
    ft->irq = avr_alloc_irq(&avr->irq_pool, 0, 2, ft_irq_names);
    avr_irq_register_notify(ft->irq + TWI_IRQ_OUTPUT, ft_twi_hook, ft);
    avr_connect_irq(ft->irq + TWI_IRQ_INPUT,
                    avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT));
    avr_connect_irq(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT),
                    ft->irq + TWI_IRQ_OUTPUT);
}

/* ------------------------------------------------------------------ the UART bridge */
static void uart_out_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    if (!S.host) {
        S.bytes_dropped++;
        return;
    }
    if (S.out_len == OUT_CAP) { /* cannot happen: the AVR pauses at OUT_HIGH */
        S.bytes_dropped++;
        return;
    }
    S.out[(S.out_head + S.out_len) % OUT_CAP] = (uint8_t)value;
    S.out_len++;
    S.bytes_out++;
}

static void uart_xon_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)value;
    (void)param;
    S.xon = 1;
}

static void uart_xoff_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)value;
    (void)param;
    S.xon = 0;
}

static avr_irq_t *uart_in;

static void pump_input(void) {
    size_t k = 0;
    while (S.xon && k < S.in_len) {
        avr_raise_irq(uart_in, S.in[k++]);
        S.bytes_in++;
    }
    memmove(S.in, S.in + k, S.in_len - k);
    S.in_len -= k;
}

static void to_avr(const char *data, size_t n) {
    if (S.in_len + n > IN_CAP) n = IN_CAP - S.in_len; /* the host sent 4 KB unread: drop */
    memcpy(S.in + S.in_len, data, n);
    S.in_len += n;
}

/* Whether an unfinished line may still be the bench finger's ("touch X Y Z" or "lift"). */
static int finger_candidate(const char *line, size_t n) {
    static const char lift[] = "lift\r";
    if (n >= 6 && strncmp(line, "touch ", 6) == 0) return 1;
    if (n <= 6 && strncmp(line, "touch ", n) == 0) return 1;
    return n <= 5 && strncmp(line, lift, n) == 0;
}

static void to_feed(const char *line, size_t n) {
    if (S.feed_fd >= 0 && (write_full(S.feed_fd, "T", 1) || write_full(S.feed_fd, line, n)))
        stop_requested = 1;
    S.finger_lines++;
}

/* Host bytes go to the AVR at once, except whole lines that are the bench finger's. */
static void from_host(const char *data, size_t n) {
    for (size_t i = 0; i < n; i++) {
        const char c = data[i];
        if (S.line_mode == 1) { /* the rest of a line for the board */
            to_avr(&c, 1);
            if (c == '\n') S.line_mode = 0;
            continue;
        }
        if (S.line_len < sizeof S.line - 1) S.line[S.line_len++] = c;
        if (c == '\n') {
            size_t k = S.line_len - 1;
            if (k && S.line[k - 1] == '\r') k--;
            int finger = (k >= 6 && strncmp(S.line, "touch ", 6) == 0) ||
                         (k == 4 && strncmp(S.line, "lift", 4) == 0);
            if (finger) to_feed(S.line, S.line_len);
            else to_avr(S.line, S.line_len);
            S.line_len = 0;
        } else if (!finger_candidate(S.line, S.line_len)) {
            to_avr(S.line, S.line_len);
            S.line_len = 0;
            S.line_mode = 1;
        }
    }
}

static void make_pty(void) {
    S.master = posix_openpt(O_RDWR | O_NOCTTY);
    if (S.master < 0 || grantpt(S.master) || unlockpt(S.master)) die("cannot open a pty");
    const char *name = ptsname(S.master);
    if (!name) die("ptsname");
    snprintf(S.slave_name, sizeof S.slave_name, "%s", name);
    /* Raw mode now: with the tty's echo on, bytes written for the host would come back. */
    int slave = open(S.slave_name, O_RDWR | O_NOCTTY);
    if (slave < 0) die("cannot open the pty's slave");
    struct termios tio;
    tcgetattr(slave, &tio);
    cfmakeraw(&tio);
    tcsetattr(slave, TCSANOW, &tio);
    close(slave);
    S.inotify = inotify_init1(IN_NONBLOCK | IN_CLOEXEC);
    if (S.inotify < 0 || inotify_add_watch(S.inotify, S.slave_name, IN_OPEN | IN_CLOSE) < 0)
        die("cannot watch the pty");
    fcntl(S.master, F_SETFL, fcntl(S.master, F_GETFL) | O_NONBLOCK);
}

static void reset_board(void) {
    avr_reset(S.avr);
    S.ft.scanning = 0; /* avr_reset dropped its timer */
    S.ft.regs[0] = 0;
    S.in_len = 0;
    S.line_len = 0;
    S.line_mode = 0;
    S.resets++;
    /* the feed's frames count from here: the firmware's frame k is the k-th scan after this */
    if (S.feed_fd >= 0 && write_full(S.feed_fd, "R", 1)) stop_requested = 1;
}

/* Move bytes between the pty and the AVR. Who holds the port comes from inotify: a host that
 * closes and reopens the port at once is a new session (an Uno resets on it), which polling
 * the master for POLLHUP would miss. */
static void service_pty(int timeout_ms) {
    struct pollfd p = {.fd = S.master, .events = POLLIN | (S.out_len ? POLLOUT : 0)};
    if (S.host) poll(&p, 1, timeout_ms);
    int opened = 0;
    char ev[1024] __attribute__((aligned(__alignof__(struct inotify_event))));
    ssize_t k;
    while ((k = read(S.inotify, ev, sizeof ev)) > 0) {
        for (char *e = ev; e < ev + k;) {
            const struct inotify_event *event = (const struct inotify_event *)e;
            const uint32_t mask = event->mask;
            e += sizeof(struct inotify_event) + event->len;
            if (mask & IN_OPEN) S.n_open++, opened = 1;
            if (mask & (IN_CLOSE_WRITE | IN_CLOSE_NOWRITE)) S.n_open--;
        }
    }
    if (opened && S.n_open > 0) {
        /* give the host 50 ms to set the port up, then reset the board as DTR would */
        usleep(50000);
        S.host = 1;
        S.host_opens++;
        S.out_len = 0;
        /* what an earlier host left unread is not this host's: a new USB session starts empty */
        tcflush(S.master, TCIOFLUSH);
        S.paced_from = S.avr->cycle, S.paced_start = now_s();
        if (S.reset_on_open) reset_board();
        return;
    }
    if (S.n_open <= 0 && S.host) {
        S.host = 0;
        S.bytes_dropped += S.out_len;
        S.out_len = 0;
    }
    if (!S.host) return;
    if (p.revents & POLLIN) {
        char buf[512];
        ssize_t k = read(S.master, buf, sizeof buf);
        if (k > 0) from_host(buf, (size_t)k);
    }
    while (S.out_len) {
        size_t chunk = S.out_len;
        if (S.out_head + chunk > OUT_CAP) chunk = OUT_CAP - S.out_head;
        ssize_t k = write(S.master, S.out + S.out_head, chunk);
        if (k <= 0) break;
        S.out_head = (S.out_head + (size_t)k) % OUT_CAP;
        S.out_len -= (size_t)k;
    }
}

static void no_sleep(avr_t *avr, avr_cycle_count_t how_long) {
    (void)avr;
    (void)how_long; /* we pace the emulation ourselves */
}

/* One line of JSON with every counter (at exit, and on SIGUSR1). */
static void print_stats(double start) {
    printf("{\"cycles\": %llu, \"emulated_s\": %.6f, \"wall_s\": %.3f, \"scans\": %llu, "
           "\"raw_reads\": %llu, \"early_reads\": %llu, \"bad_tx\": %llu, "
           "\"reads_while_scanning\": %llu, \"gain_writes\": %llu, \"gain\": %d, \"naks\": %llu, "
           "\"bus_bytes\": %llu, "
           "\"bytes_out\": %llu, \"bytes_in\": %llu, \"bytes_dropped\": %llu, "
           "\"bytes_unsent\": %zu, \"out_stalls\": %llu, \"host_opens\": %llu, "
           "\"resets\": %llu, \"finger_lines\": %llu, \"data_end\": %u, \"min_sp\": %u, "
           "\"stack_headroom\": %d, \"fault\": \"%s\"}\n",
           (unsigned long long)S.avr->cycle, S.avr->cycle / 16e6, now_s() - start,
           (unsigned long long)S.ft.scans, (unsigned long long)S.ft.raw_reads,
           (unsigned long long)S.ft.early_reads, (unsigned long long)S.ft.bad_tx,
           (unsigned long long)S.ft.reads_while_scanning, (unsigned long long)S.ft.gain_writes,
           S.ft.gain, (unsigned long long)S.ft.naks, (unsigned long long)S.ft.bus_bytes,
           (unsigned long long)S.bytes_out,
           (unsigned long long)S.bytes_in, (unsigned long long)S.bytes_dropped, S.out_len,
           (unsigned long long)S.out_stalls, (unsigned long long)S.host_opens,
           (unsigned long long)S.resets, (unsigned long long)S.finger_lines, S.data_end,
           S.min_sp, (int)S.min_sp - (int)S.data_end, S.fault);
    fflush(stdout);
}

/* ------------------------------------------------------------------ main */
static void usage(void) {
    fprintf(stderr,
            "usage: skinloc_avrsim FIRMWARE.elf [--controller ok|missing|silent] [--scan-us N]\n"
            "       [--speed X] [--feed-fd N] [--dead-rx R] [--dead-tx T] [--seconds S]\n"
            "       [--no-reset-on-open] [--trace-twi]\n");
    exit(2);
}

int main(int argc, char **argv) {
    const char *elf = NULL;
    S.ft.mode = CTRL_OK;
    S.ft.scan_us = 1000;
    S.feed_fd = -1;
    S.speed = 1.0;
    S.reset_on_open = 1;
    S.fault = "none";
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *val = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--controller") == 0 && val) {
            S.ft.mode = !strcmp(val, "ok") ? CTRL_OK : !strcmp(val, "missing") ? CTRL_MISSING
                      : !strcmp(val, "silent")                                 ? CTRL_SILENT
                                                                               : -1;
            if (S.ft.mode < 0) usage();
            i++;
        } else if (strcmp(a, "--scan-us") == 0 && val) {
            S.ft.scan_us = (uint32_t)strtoul(val, NULL, 10), i++;
        } else if (strcmp(a, "--speed") == 0 && val) {
            S.speed = strtod(val, NULL), i++;
        } else if (strcmp(a, "--feed-fd") == 0 && val) {
            S.feed_fd = atoi(val), i++;
        } else if (strcmp(a, "--dead-rx") == 0 && val) {
            S.dead_rx |= 1u << (atoi(val) & 15), i++;
        } else if (strcmp(a, "--dead-tx") == 0 && val) {
            S.dead_tx |= 1u << (atoi(val) % 21), i++;
        } else if (strcmp(a, "--seconds") == 0 && val) {
            S.seconds = strtod(val, NULL), i++;
        } else if (strcmp(a, "--no-reset-on-open") == 0) {
            S.reset_on_open = 0;
        } else if (strcmp(a, "--trace-twi") == 0) {
            S.trace_twi = 1;
        } else if (a[0] != '-' && !elf) {
            elf = a;
        } else {
            usage();
        }
    }
    if (!elf) usage();
    /* An emulator left behind by a killed test would spin a core forever: die with the parent. */
    prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (getppid() == 1) return 2;

    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(elf, &fw) != 0) {
        fprintf(stderr, "skinloc_avrsim: cannot read %s\n", elf);
        return 2;
    }
    S.avr = avr_make_mcu_by_name("atmega328p");
    if (!S.avr) return 2;
    avr_init(S.avr);
    S.avr->log = 1; /* errors only: a fault is reported on stderr */
    fw.frequency = 16000000;
    avr_load_firmware(S.avr, &fw);
    S.avr->frequency = 16000000;
    S.avr->sleep = no_sleep;
    /* .data and .bss start at RAMSTART (0x100 on the ATmega328P); the stack must stay above */
    S.data_end = (uint16_t)(0x100 + fw.datasize + fw.bsssize);
    S.min_sp = 0xFFFF;

    uint32_t flags = 0;
    avr_ioctl(S.avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
    avr_ioctl(S.avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(S.avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            uart_out_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(S.avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                            uart_xon_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(S.avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                            uart_xoff_hook, NULL);
    uart_in = avr_io_getirq(S.avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    ft_init(S.avr, &S.ft);

    make_pty();
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGPIPE, SIG_IGN);
    signal(SIGUSR1, on_usr1);
    printf("pty %s\n", S.slave_name);
    fflush(stdout);

    const double start = now_s();
    const avr_cycle_count_t slice = 16000; /* 1 ms of emulated time between pty services */
    S.paced_from = 0, S.paced_start = start;
    int state = cpu_Running;
    while (!stop_requested) {
        if (S.seconds > 0 && now_s() - start > S.seconds) break;
        if (stats_requested) stats_requested = 0, print_stats(start);
        service_pty(0);
        if (S.host && S.out_len >= OUT_HIGH) {
            /* the host reads slower than the firmware writes: wait for it, AVR stopped */
            S.out_stalls++;
            service_pty(5);
            S.paced_from = S.avr->cycle, S.paced_start = now_s();
            continue;
        }
        if (!S.host) {
            /* nobody listens: run on, at the pace asked, as a board on a closed port does */
        }
        pump_input();
        const avr_cycle_count_t until = S.avr->cycle + slice;
        while (S.avr->cycle < until) {
            state = avr_run(S.avr);
            uint16_t sp = (uint16_t)(S.avr->data[0x5D] | S.avr->data[0x5E] << 8);
            if (sp < S.min_sp) S.min_sp = sp;
            if (state == cpu_Done || state == cpu_Crashed) break;
        }
        if (state == cpu_Crashed) {
            S.fault = "crashed (invalid memory access or opcode; see stderr)";
            break;
        }
        if (state == cpu_Done) {
            S.fault = "the firmware stopped (cli; sleep)";
            break;
        }
        if (S.data_end && S.min_sp < S.data_end) {
            S.fault = "stack overflow: the stack ran into .data/.bss";
            break;
        }
        if (S.speed > 0) {
            double ahead =
                (S.avr->cycle - S.paced_from) / 16e6 / S.speed - (now_s() - S.paced_start);
            if (ahead > 0.01) ahead = 0.01; /* wait in short steps: a host may arrive */
            if (ahead < -0.1) /* fell behind (a busy machine): go on from now, no burst */
                S.paced_from = S.avr->cycle, S.paced_start = now_s();
            /* sleep, not poll: poll returns at once while output waits (POLLOUT) */
            if (ahead > 0.002) usleep((useconds_t)(ahead * 1e6));
        }
    }
    /* hand the host what the firmware already sent (at most 1 s) */
    for (int k = 0; k < 200 && S.host && S.out_len; k++) service_pty(5);

    print_stats(start);
    fflush(stdout);
    return strcmp(S.fault, "none") == 0 ? 0 : 3;
}
