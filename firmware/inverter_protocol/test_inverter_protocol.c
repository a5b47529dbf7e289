/* Host unit test of the C codec against test_vectors.txt (the vectors the Python codec is tested
 * with), plus stream resynchronisation. Usage: test_inverter_protocol test_vectors.txt */
#include "inverter_protocol.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int failures = 0;
#define CHECK(cond, ...) do { if (!(cond)) { failures++; printf("FAIL line %d: ", line_no); \
    printf(__VA_ARGS__); printf("\n"); } } while (0)
static int line_no = 0;

static size_t from_hex(const char *text, uint8_t *out, size_t cap) {
    size_t n = 0;
    while (text[0] && text[1] && n < cap) {
        unsigned v;
        if (sscanf(text, "%2x", &v) != 1) break;
        out[n++] = (uint8_t)v;
        text += 2;
    }
    return n;
}

static float from_bits(unsigned long bits) { uint32_t u = (uint32_t)bits; float f; memcpy(&f, &u, 4); return f; }

/* Parse "TYPE fields..." into m; returns the number of characters consumed, 0 on error. */
static int parse_message(const char *s, ip_message_t *m) {
    char type[16];
    int used = 0, more = 0;
    memset(m, 0, sizeof *m);
    if (sscanf(s, "%15s%n", type, &used) != 1) return 0;
    s += used;
    if (!strcmp(type, "TELEMETRY")) {
        unsigned long seq; int a, b, c; unsigned u, e, st;
        if (sscanf(s, "%lu %d %d %d %u %u %u%n", &seq, &a, &b, &c, &u, &e, &st, &more) != 7) return 0;
        m->type = IP_TELEMETRY; m->u.telemetry = (ip_telemetry_t){(uint32_t)seq, (int16_t)a, (int16_t)b,
            (int16_t)c, (uint16_t)u, (uint16_t)e, (uint16_t)st};
    } else if (!strcmp(type, "HELLO")) {
        unsigned id, fl, np, bs, wd; unsigned long ts, ci, vo, tr;
        if (sscanf(s, "%u %u %u %u %lu %lx %lx %lx %u%n", &id, &fl, &np, &bs, &ts, &ci, &vo, &tr, &wd, &more) != 9)
            return 0;
        m->type = IP_HELLO; m->u.hello = (ip_hello_t){(uint8_t)id, (uint8_t)fl, (uint8_t)np, (uint8_t)bs,
            (uint32_t)ts, from_bits(ci), from_bits(vo), from_bits(tr), (uint16_t)wd};
    } else if (!strcmp(type, "TELEMETRY_BLOCK")) {
        unsigned long seq; unsigned u, st, count;
        ip_telemetry_block_t *t = &m->u.telemetry_block;
        if (sscanf(s, "%lu %u %u %u%n", &seq, &u, &st, &count, &more) != 4 || count > IP_MAX_BLOCK) return 0;
        m->type = IP_TELEMETRY_BLOCK;
        t->seq = (uint32_t)seq; t->u_dc = (uint16_t)u; t->status = (uint16_t)st; t->count = (uint8_t)count;
        for (unsigned i = 0; i < count; i++) {
            int a, b, c, step; unsigned e;
            if (sscanf(s + more, "%d %d %d %u%n", &a, &b, &c, &e, &step) != 4) return 0;
            t->s[i].i_a = (int16_t)a; t->s[i].i_b = (int16_t)b; t->s[i].i_c = (int16_t)c; t->s[i].encoder = (uint16_t)e;
            more += step;
        }
    } else if (!strcmp(type, "COMMAND_BLOCK")) {
        unsigned long seq; unsigned fl, count;
        ip_command_block_t *c = &m->u.command_block;
        if (sscanf(s, "%lu %u %u%n", &seq, &fl, &count, &more) != 3 || count > IP_MAX_BLOCK) return 0;
        m->type = IP_COMMAND_BLOCK;
        c->seq = (uint32_t)seq; c->flags = (uint8_t)fl; c->count = (uint8_t)count;
        for (unsigned i = 0; i < count; i++) {
            int a, b, step;
            if (sscanf(s + more, "%d %d%n", &a, &b, &step) != 2) return 0;
            c->s[i].u_alpha = (int16_t)a; c->s[i].u_beta = (int16_t)b;
            more += step;
        }
    } else if (!strcmp(type, "COMMAND")) {
        unsigned long seq; int a, b; unsigned fl;
        if (sscanf(s, "%lu %d %d %u%n", &seq, &a, &b, &fl, &more) != 4) return 0;
        m->type = IP_COMMAND; m->u.command = (ip_command_t){(uint32_t)seq, (int16_t)a, (int16_t)b, (uint8_t)fl};
    } else if (!strcmp(type, "CONTROL")) {
        unsigned action;
        if (sscanf(s, "%u%n", &action, &more) != 1) return 0;
        m->type = IP_CONTROL; m->u.control.action = (uint8_t)action;
    } else if (!strcmp(type, "HEARTBEAT")) {
        unsigned long counter;
        if (sscanf(s, "%lu%n", &counter, &more) != 1) return 0;
        m->type = IP_HEARTBEAT; m->u.heartbeat.counter = (uint32_t)counter;
    } else {
        return 0;
    }
    return used + more;
}

static int same(const ip_message_t *a, const ip_message_t *b, int seq_bits16) {
    ip_message_t x = *a, y = *b;
    if (seq_bits16) {
        if (x.type == IP_TELEMETRY) { x.u.telemetry.seq &= 0xFFFF; y.u.telemetry.seq &= 0xFFFF; }
        if (x.type == IP_COMMAND) { x.u.command.seq &= 0xFFFF; y.u.command.seq &= 0xFFFF; }
    }
    if (x.type != y.type) return 0;
    switch (x.type) {
    case IP_TELEMETRY: return !memcmp(&x.u.telemetry, &y.u.telemetry, sizeof x.u.telemetry);
    case IP_HELLO: {
        const ip_hello_t *p = &x.u.hello, *q = &y.u.hello;
        return p->drive_id == q->drive_id && p->flags == q->flags && p->n_p == q->n_p
            && p->block_samples == q->block_samples && p->T_s_ns == q->T_s_ns
            && !memcmp(&p->current_lsb_A, &q->current_lsb_A, 4) && !memcmp(&p->voltage_lsb_V, &q->voltage_lsb_V, 4)
            && !memcmp(&p->trip_current_A, &q->trip_current_A, 4) && p->watchdog_periods == q->watchdog_periods;
    }
    case IP_COMMAND: return x.u.command.seq == y.u.command.seq && x.u.command.u_alpha == y.u.command.u_alpha
        && x.u.command.u_beta == y.u.command.u_beta && x.u.command.flags == y.u.command.flags;
    case IP_CONTROL: return x.u.control.action == y.u.control.action;
    case IP_HEARTBEAT: return x.u.heartbeat.counter == y.u.heartbeat.counter;
    case IP_TELEMETRY_BLOCK: {
        const ip_telemetry_block_t *p = &x.u.telemetry_block, *q = &y.u.telemetry_block;
        if (p->seq != q->seq || p->u_dc != q->u_dc || p->status != q->status || p->count != q->count) return 0;
        for (unsigned i = 0; i < p->count; i++)
            if (p->s[i].i_a != q->s[i].i_a || p->s[i].i_b != q->s[i].i_b || p->s[i].i_c != q->s[i].i_c
                || p->s[i].encoder != q->s[i].encoder) return 0;
        return 1;
    }
    case IP_COMMAND_BLOCK: {
        const ip_command_block_t *p = &x.u.command_block, *q = &y.u.command_block;
        if (p->seq != q->seq || p->flags != q->flags || p->count != q->count) return 0;
        for (unsigned i = 0; i < p->count; i++)
            if (p->s[i].u_alpha != q->s[i].u_alpha || p->s[i].u_beta != q->s[i].u_beta) return 0;
        return 1;
    }
    default: return 0;
    }
}

static void serial_vector(const char *s) {
    ip_message_t m, back;
    int used = parse_message(s, &m);
    CHECK(used > 0, "unparsable message");
    const char *eq = strchr(s + used, '=');
    uint8_t expected[IP_MAX_WIRE + 8], wire[IP_MAX_WIRE];
    size_t n_expected = from_hex(eq + 2, expected, sizeof expected);
    size_t n = ip_encode(&m, wire, sizeof wire);
    CHECK(n == n_expected && !memcmp(wire, expected, n), "encoding differs from the vector");
    CHECK(ip_decode(expected, n_expected - 1, &back) == IP_OK && same(&m, &back, 0), "decoding differs");
    ip_reader_t r;
    ip_reader_init(&r);
    int got = 0;
    for (size_t i = 0; i < n_expected; i++) got = ip_reader_push(&r, expected[i], &back);
    CHECK(got == 1 && same(&m, &back, 0), "reader did not return the message");
}

/* The drive and message of a CAN vector ("DRIVE TYPE fields... = id:hex ..."), and up to max of its
 * frames (each at most cap data bytes: 8 classic, 64 CAN FD); returns the number of frames, -1 if the
 * message is unparsable. */
static int parse_can_vector(const char *s, unsigned *drive, ip_message_t *m, ip_canfd_frame_t *frames, int max,
                            size_t cap) {
    int used = 0, step, n = 0;
    sscanf(s, "%u%n", drive, &used);
    int more = parse_message(s + used, m);
    if (more <= 0) return -1;
    const char *p = strchr(s + used + more, '=') + 1;
    unsigned id;
    char hex[140];
    while (n < max && sscanf(p, " %x:%139s%n", &id, hex, &step) == 2) {
        frames[n].id = (uint16_t)id;
        frames[n].len = (uint8_t)from_hex(hex, frames[n].data, cap);
        n++;
        p += step;
    }
    return n;
}

static void can_vector(const char *s) {
    unsigned drive;
    ip_message_t m, back;
    ip_canfd_frame_t given[3];
    int n_expected = parse_can_vector(s, &drive, &m, given, 3, 8);
    CHECK(n_expected > 0, "unparsable CAN vector");
    ip_can_frame_t frames[3], expected[3];
    for (int i = 0; i < n_expected; i++) {
        expected[i].id = given[i].id;
        expected[i].dlc = given[i].len;
        memcpy(expected[i].data, given[i].data, 8);
    }
    size_t n = ip_can_encode(&m, (uint8_t)drive, frames);
    CHECK(n == (size_t)n_expected, "%zu CAN frames, vector has %d", n, n_expected);
    for (size_t i = 0; i < n && i < (size_t)n_expected; i++)
        CHECK(frames[i].id == expected[i].id && frames[i].dlc == expected[i].dlc
              && !memcmp(frames[i].data, expected[i].data, frames[i].dlc), "CAN frame %zu differs", i);
    ip_can_decoder_t d;
    ip_can_decoder_init(&d, (uint8_t)drive);
    int got = 0;
    for (int i = 0; i < n_expected; i++) got = ip_can_decode(&d, &expected[i], &back);
    CHECK(got == 1 && same(&m, &back, 1), "CAN decoding differs");
}

static void canfd_vector(const char *s) {
    unsigned drive;
    ip_message_t m, back, whole;
    ip_canfd_frame_t frames[IP_CANFD_MAX_FRAMES], expected[IP_CANFD_MAX_FRAMES];
    int n_expected = parse_can_vector(s, &drive, &m, expected, IP_CANFD_MAX_FRAMES, 64);
    CHECK(n_expected > 0, "unparsable CAN FD vector");
    size_t n = ip_canfd_encode(&m, (uint8_t)drive, frames);
    CHECK(n == (size_t)n_expected, "%zu CAN FD frames, vector has %d", n, n_expected);
    for (size_t i = 0; i < n && i < (size_t)n_expected; i++)
        CHECK(frames[i].id == expected[i].id && frames[i].len == expected[i].len
              && !memcmp(frames[i].data, expected[i].data, frames[i].len), "CAN FD frame %zu differs", i);
    whole = m;
    unsigned total = 0;
    for (int i = 0; i < n_expected; i++) {
        CHECK(ip_canfd_decode((uint8_t)drive, &expected[i], &back) == IP_OK, "CAN FD frame %d not decoded", i);
        if (back.type == IP_TELEMETRY_BLOCK) {
            CHECK(back.u.telemetry_block.seq == m.u.telemetry_block.seq + total, "CAN FD chunk seq");
            memcpy(whole.u.telemetry_block.s + total, back.u.telemetry_block.s,
                   back.u.telemetry_block.count * sizeof back.u.telemetry_block.s[0]);
            total += back.u.telemetry_block.count;
            whole.u.telemetry_block.u_dc = back.u.telemetry_block.u_dc;
            whole.u.telemetry_block.status = back.u.telemetry_block.status;
        } else {
            CHECK(back.u.command_block.seq == m.u.command_block.seq + total, "CAN FD chunk seq");
            memcpy(whole.u.command_block.s + total, back.u.command_block.s,
                   back.u.command_block.count * sizeof back.u.command_block.s[0]);
            total += back.u.command_block.count;
            whole.u.command_block.flags = back.u.command_block.flags;
        }
    }
    CHECK(total == (m.type == IP_TELEMETRY_BLOCK ? m.u.telemetry_block.count : m.u.command_block.count)
          && same(&m, &whole, 0), "CAN FD decoding differs");
}

static void bad_vector(const char *s) {
    char hex[200], kind[32];
    uint8_t frame[100];
    ip_message_t m;
    CHECK(sscanf(s, "%199s %31s", hex, kind) == 2, "unparsable bad vector");
    size_t n = from_hex(hex, frame, sizeof frame);
    int r = ip_decode(frame, n, &m);
    int expected = !strcmp(kind, "crc") ? IP_ERR_CRC : !strcmp(kind, "version") ? IP_ERR_VERSION
                 : !strcmp(kind, "unknown_type") ? IP_ERR_TYPE : IP_ERR_FRAMING;
    CHECK(r == expected, "bad frame %s: got %d, expected %d (%s)", hex, r, expected, kind);
}

static void safe_vector(const char *s) {
    unsigned flags, state;
    CHECK(sscanf(s, "%u = %u", &flags, &state) == 2, "unparsable safe vector");
    CHECK((unsigned)ip_requested_safe_state((uint8_t)flags) == state, "safe %u: got %d, expected %u", flags,
          (int)ip_requested_safe_state((uint8_t)flags), state);
    unsigned asked = (flags & IP_SAFE_STATE_MASK) >> IP_SAFE_STATE_SHIFT;
    if (asked == state)
        CHECK(ip_command_flags((int)(flags & IP_ENABLE), (enum ip_safe_state)state) == (flags & 0x07u),
              "command flags of %u", flags);
}

static void stream_resynchronises(void) {
    ip_message_t m = {.type = IP_COMMAND, .u.command = {42, -5, 6, IP_ENABLE}}, back;
    uint8_t wire[IP_MAX_WIRE], noise[] = {0x13, 0x37, 0xFF, 0x00, 0x05, 0x00};
    size_t n = ip_encode(&m, wire, sizeof wire);
    ip_reader_t r;
    ip_reader_init(&r);
    int bad = 0, good = 0;
    for (size_t i = 0; i < sizeof noise; i++) bad += ip_reader_push(&r, noise[i], &back) < 0;
    for (int rep = 0; rep < 3; rep++)
        for (size_t i = 0; i < n; i++) good += ip_reader_push(&r, wire[i], &back) == 1;
    for (int i = 0; i < 200; i++) ip_reader_push(&r, 0x55, &back);
    bad += ip_reader_push(&r, 0, &back) < 0;
    for (size_t i = 0; i < n; i++) good += ip_reader_push(&r, wire[i], &back) == 1;
    CHECK(bad == 3 && good == 4 && same(&m, &back, 0), "stream: %d bad, %d good frames", bad, good);
    CHECK(ip_unwrap16(0x0002, 0xFFFFFFFEu) == 2u && ip_unwrap16(0xFFFE, 3u) == 0xFFFFFFFEu
          && ip_unwrap16(0x1234, 0x00051200u) == 0x00051234u, "unwrap16");
    uint8_t small[4];
    CHECK(ip_encode(&m, small, sizeof small) == 0, "encode into a too small buffer must fail");
    ip_message_t empty = {.type = IP_COMMAND_BLOCK, .u.command_block = {.seq = 1, .flags = IP_ENABLE, .count = 0}};
    CHECK(ip_encode(&empty, wire, sizeof wire) == 0, "a block of no samples must not encode");
    CHECK(ip_crc16((const uint8_t *)"123456789", 9) == 0x29B1, "CRC check value");
}

int main(int argc, char **argv) {
    if (argc != 2) { fprintf(stderr, "usage: %s test_vectors.txt\n", argv[0]); return 2; }
    FILE *f = fopen(argv[1], "r");
    if (!f) { perror(argv[1]); return 2; }
    char text[2048];
    int vectors = 0;
    while (fgets(text, sizeof text, f)) {
        line_no++;
        if (!strncmp(text, "serial ", 7)) serial_vector(text + 7), vectors++;
        else if (!strncmp(text, "can ", 4)) can_vector(text + 4), vectors++;
        else if (!strncmp(text, "canfd ", 6)) canfd_vector(text + 6), vectors++;
        else if (!strncmp(text, "bad ", 4)) bad_vector(text + 4), vectors++;
        else if (!strncmp(text, "safe ", 5)) safe_vector(text + 5), vectors++;
    }
    fclose(f);
    line_no = 0;
    stream_resynchronises();
    printf("%d vectors, %d failures\n", vectors, failures);
    return failures != 0;
}
