/* Inverter wire protocol, version 2: see inverter_protocol.h and docs/inverter-protocol.md. */
#include "inverter_protocol.h"

#include <string.h>

static void put16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put32(uint8_t *p, uint32_t v) { put16(p, (uint16_t)v); put16(p + 2, (uint16_t)(v >> 16)); }
static void putf(uint8_t *p, float v) { uint32_t u; memcpy(&u, &v, 4); put32(p, u); }
static uint16_t get16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static uint32_t get32(const uint8_t *p) { return get16(p) | ((uint32_t)get16(p + 2) << 16); }
static float getf(const uint8_t *p) { uint32_t u = get32(p); float v; memcpy(&v, &u, 4); return v; }

uint16_t ip_crc16(const uint8_t *data, size_t len) {
    uint16_t crc = 0xFFFFu;
    for (size_t i = 0; i < len; i++) {
        crc ^= (uint16_t)(data[i] << 8);
        for (int b = 0; b < 8; b++) crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
    }
    return crc;
}

uint8_t ip_command_flags(int enable, enum ip_safe_state safe) {
    return (uint8_t)((enable ? IP_ENABLE : 0u) | (((unsigned)safe << IP_SAFE_STATE_SHIFT) & IP_SAFE_STATE_MASK));
}

enum ip_safe_state ip_requested_safe_state(uint8_t flags) {
    unsigned state = (flags & IP_SAFE_STATE_MASK) >> IP_SAFE_STATE_SHIFT;
    return state == IP_SAFE_FREEWHEEL ? IP_SAFE_FREEWHEEL : state == IP_SAFE_ASC ? IP_SAFE_ASC : IP_SAFE_AUTO;
}

size_t ip_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap) {
    size_t code_at = 0, o = 1;
    uint8_t code = 1;
    if (cap == 0) return 0;
    for (size_t i = 0; i < len; i++) {
        if (in[i] == 0) {
            out[code_at] = code; code_at = o++; code = 1;
            if (o > cap) return 0;
        } else {
            if (o >= cap) return 0;
            out[o++] = in[i];
            if (++code == 0xFF) {
                out[code_at] = code; code_at = o++; code = 1;
                if (o > cap) return 0;
            }
        }
    }
    out[code_at] = code;
    return o;
}

int ip_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len) {
    size_t i = 0, o = 0;
    while (i < len) {
        uint8_t code = in[i];
        if (code == 0 || i + code > len) return IP_ERR_FRAMING;
        for (size_t j = i + 1; j < i + code; j++) {
            if (in[j] == 0) return IP_ERR_FRAMING;
            if (o >= cap) return IP_ERR_SPACE;
            out[o++] = in[j];
        }
        i += code;
        if (code < 0xFF && i < len) {
            if (o >= cap) return IP_ERR_SPACE;
            out[o++] = 0;
        }
    }
    *out_len = o;
    return IP_OK;
}

/* Body bytes of a message of this type carrying count samples (blocks), 0 for an unknown type or a
 * count outside 1 .. IP_MAX_BLOCK. */
static size_t body_size(uint8_t type, unsigned count) {
    int block_ok = count >= 1u && count <= IP_MAX_BLOCK;
    switch (type) {
    case IP_TELEMETRY: return 16;
    case IP_HELLO: return 22;
    case IP_TELEMETRY_BLOCK: return block_ok ? 9u + 8u * count : 0;
    case IP_COMMAND: return 9;
    case IP_CONTROL: return 1;
    case IP_HEARTBEAT: return 4;
    case IP_COMMAND_BLOCK: return block_ok ? 6u + 4u * count : 0;
    default: return 0;
    }
}

static unsigned count_of(const ip_message_t *m) {
    if (m->type == IP_TELEMETRY_BLOCK) return m->u.telemetry_block.count;
    if (m->type == IP_COMMAND_BLOCK) return m->u.command_block.count;
    return 1u;
}

static void pack_body(const ip_message_t *m, uint8_t *b) {
    switch (m->type) {
    case IP_TELEMETRY: {
        const ip_telemetry_t *t = &m->u.telemetry;
        put32(b, t->seq); put16(b + 4, (uint16_t)t->i_a); put16(b + 6, (uint16_t)t->i_b);
        put16(b + 8, (uint16_t)t->i_c); put16(b + 10, t->u_dc); put16(b + 12, t->encoder); put16(b + 14, t->status);
        break;
    }
    case IP_HELLO: {
        const ip_hello_t *h = &m->u.hello;
        b[0] = h->drive_id; b[1] = h->flags; b[2] = h->n_p; b[3] = h->block_samples; put32(b + 4, h->T_s_ns);
        putf(b + 8, h->current_lsb_A); putf(b + 12, h->voltage_lsb_V); putf(b + 16, h->trip_current_A);
        put16(b + 20, h->watchdog_periods);
        break;
    }
    case IP_COMMAND:
        put32(b, m->u.command.seq); put16(b + 4, (uint16_t)m->u.command.u_alpha);
        put16(b + 6, (uint16_t)m->u.command.u_beta); b[8] = m->u.command.flags;
        break;
    case IP_CONTROL: b[0] = m->u.control.action; break;
    case IP_HEARTBEAT: put32(b, m->u.heartbeat.counter); break;
    case IP_TELEMETRY_BLOCK: {
        const ip_telemetry_block_t *t = &m->u.telemetry_block;
        put32(b, t->seq); put16(b + 4, t->u_dc); put16(b + 6, t->status); b[8] = t->count;
        for (unsigned i = 0; i < t->count; i++) {
            uint8_t *e = b + 9 + 8 * i;
            put16(e, (uint16_t)t->s[i].i_a); put16(e + 2, (uint16_t)t->s[i].i_b);
            put16(e + 4, (uint16_t)t->s[i].i_c); put16(e + 6, t->s[i].encoder);
        }
        break;
    }
    case IP_COMMAND_BLOCK: {
        const ip_command_block_t *c = &m->u.command_block;
        put32(b, c->seq); b[4] = c->flags; b[5] = c->count;
        for (unsigned i = 0; i < c->count; i++) {
            put16(b + 6 + 4 * i, (uint16_t)c->s[i].u_alpha); put16(b + 8 + 4 * i, (uint16_t)c->s[i].u_beta);
        }
        break;
    }
    default: break;
    }
}

static void unpack_body(uint8_t type, const uint8_t *b, ip_message_t *m) {
    m->type = type;
    switch (type) {
    case IP_TELEMETRY: {
        ip_telemetry_t *t = &m->u.telemetry;
        t->seq = get32(b); t->i_a = (int16_t)get16(b + 4); t->i_b = (int16_t)get16(b + 6);
        t->i_c = (int16_t)get16(b + 8); t->u_dc = get16(b + 10); t->encoder = get16(b + 12); t->status = get16(b + 14);
        break;
    }
    case IP_HELLO: {
        ip_hello_t *h = &m->u.hello;
        h->drive_id = b[0]; h->flags = b[1]; h->n_p = b[2]; h->block_samples = b[3]; h->T_s_ns = get32(b + 4);
        h->current_lsb_A = getf(b + 8); h->voltage_lsb_V = getf(b + 12); h->trip_current_A = getf(b + 16);
        h->watchdog_periods = get16(b + 20);
        break;
    }
    case IP_COMMAND:
        m->u.command.seq = get32(b); m->u.command.u_alpha = (int16_t)get16(b + 4);
        m->u.command.u_beta = (int16_t)get16(b + 6); m->u.command.flags = b[8];
        break;
    case IP_CONTROL: m->u.control.action = b[0]; break;
    case IP_HEARTBEAT: m->u.heartbeat.counter = get32(b); break;
    case IP_TELEMETRY_BLOCK: {
        ip_telemetry_block_t *t = &m->u.telemetry_block;
        t->seq = get32(b); t->u_dc = get16(b + 4); t->status = get16(b + 6); t->count = b[8];
        for (unsigned i = 0; i < t->count; i++) {
            const uint8_t *e = b + 9 + 8 * i;
            t->s[i].i_a = (int16_t)get16(e); t->s[i].i_b = (int16_t)get16(e + 2);
            t->s[i].i_c = (int16_t)get16(e + 4); t->s[i].encoder = get16(e + 6);
        }
        break;
    }
    case IP_COMMAND_BLOCK: {
        ip_command_block_t *c = &m->u.command_block;
        c->seq = get32(b); c->flags = b[4]; c->count = b[5];
        for (unsigned i = 0; i < c->count; i++) {
            c->s[i].u_alpha = (int16_t)get16(b + 6 + 4 * i); c->s[i].u_beta = (int16_t)get16(b + 8 + 4 * i);
        }
        break;
    }
    default: break;
    }
}

size_t ip_encode(const ip_message_t *m, uint8_t *wire, size_t cap) {
    uint8_t raw[IP_MAX_FRAME];
    size_t body = body_size(m->type, count_of(m));
    if (body == 0 || cap < 1) return 0;
    raw[0] = IP_VERSION; raw[1] = m->type;
    pack_body(m, raw + 2);
    put16(raw + 2 + body, ip_crc16(raw, 2 + body));
    size_t n = ip_cobs_encode(raw, body + 4, wire, cap - 1);
    if (n == 0) return 0;
    wire[n] = 0;
    return n + 1;
}

int ip_decode(const uint8_t *frame, size_t len, ip_message_t *m) {
    uint8_t raw[IP_MAX_FRAME];
    size_t n;
    int r = ip_cobs_decode(frame, len, raw, sizeof raw, &n);
    if (r == IP_ERR_SPACE) return IP_ERR_FRAMING;
    if (r != IP_OK) return r;
    if (n < 4) return IP_ERR_FRAMING;
    if (ip_crc16(raw, n - 2) != get16(raw + n - 2)) return IP_ERR_CRC;
    if (raw[0] != IP_VERSION) return IP_ERR_VERSION;
    int block = raw[1] == IP_TELEMETRY_BLOCK || raw[1] == IP_COMMAND_BLOCK;
    size_t head = raw[1] == IP_TELEMETRY_BLOCK ? 9 : 6;
    if (block && n - 4 < head) return IP_ERR_FRAMING;
    size_t body = body_size(raw[1], block ? raw[2 + head - 1] : 1u);
    if (body == 0) return block ? IP_ERR_FRAMING : IP_ERR_TYPE;
    if (n - 4 != body) return IP_ERR_FRAMING;
    unpack_body(raw[1], raw + 2, m);
    return IP_OK;
}

void ip_reader_init(ip_reader_t *r) { r->len = 0; r->overflow = 0; }

int ip_reader_push(ip_reader_t *r, uint8_t byte, ip_message_t *m) {
    if (byte != 0) {
        if (r->len < sizeof r->buf) r->buf[r->len++] = byte;
        else r->overflow = 1;
        return 0;
    }
    size_t len = r->len;
    int overflow = r->overflow;
    ip_reader_init(r);
    if (len == 0) return 0;
    if (overflow) return IP_ERR_FRAMING;
    int result = ip_decode(r->buf, len, m);
    return result == IP_OK ? 1 : result;
}

uint32_t ip_unwrap16(uint16_t low, uint32_t last) {
    int32_t delta = (int32_t)(uint16_t)(low - (uint16_t)last);
    if (delta >= 0x8000) delta -= 0x10000;
    return last + (uint32_t)delta;
}

static size_t can_frame(ip_can_frame_t *f, uint16_t id, uint8_t dlc) {
    f->id = id; f->dlc = dlc; memset(f->data, 0, sizeof f->data);
    return 1;
}

size_t ip_can_encode(const ip_message_t *m, uint8_t drive_id, ip_can_frame_t frames[3]) {
    if (drive_id > 15) return 0;
    uint16_t base = (uint16_t)(0x100u + 0x20u * drive_id);
    switch (m->type) {
    case IP_COMMAND: {
        const ip_command_t *c = &m->u.command;
        can_frame(&frames[0], base + IP_CAN_COMMAND, 8);
        put16(frames[0].data, (uint16_t)c->seq); put16(frames[0].data + 2, (uint16_t)c->u_alpha);
        put16(frames[0].data + 4, (uint16_t)c->u_beta); frames[0].data[6] = c->flags;
        return 1;
    }
    case IP_CONTROL:
        can_frame(&frames[0], base + IP_CAN_CONTROL, 1);
        frames[0].data[0] = m->u.control.action;
        return 1;
    case IP_HEARTBEAT:
        can_frame(&frames[0], base + IP_CAN_HEARTBEAT, 4);
        put32(frames[0].data, m->u.heartbeat.counter);
        return 1;
    case IP_TELEMETRY: {
        const ip_telemetry_t *t = &m->u.telemetry;
        can_frame(&frames[0], base + IP_CAN_TELEMETRY_B, 8);
        put16(frames[0].data, (uint16_t)t->seq); put16(frames[0].data + 2, t->u_dc);
        put16(frames[0].data + 4, t->encoder); put16(frames[0].data + 6, t->status);
        can_frame(&frames[1], base + IP_CAN_TELEMETRY_A, 8);
        put16(frames[1].data, (uint16_t)t->seq); put16(frames[1].data + 2, (uint16_t)t->i_a);
        put16(frames[1].data + 4, (uint16_t)t->i_b); put16(frames[1].data + 6, (uint16_t)t->i_c);
        return 2;
    }
    case IP_HELLO: {
        const ip_hello_t *h = &m->u.hello;
        can_frame(&frames[0], base + IP_CAN_HELLO_A, 8);
        frames[0].data[0] = IP_VERSION; frames[0].data[1] = h->drive_id; frames[0].data[2] = h->flags;
        frames[0].data[3] = h->n_p; put32(frames[0].data + 4, h->T_s_ns);
        can_frame(&frames[1], base + IP_CAN_HELLO_B, 8);
        putf(frames[1].data, h->current_lsb_A); putf(frames[1].data + 4, h->voltage_lsb_V);
        can_frame(&frames[2], base + IP_CAN_HELLO_C, 8);
        putf(frames[2].data, h->trip_current_A); put16(frames[2].data + 4, h->watchdog_periods);
        frames[2].data[6] = h->block_samples;
        return 3;
    }
    default: return 0;
    }
}

int ip_can_decoder_init(ip_can_decoder_t *d, uint8_t drive_id) {
    if (drive_id > 15) return IP_ERR_TYPE;
    memset(d, 0, sizeof *d);
    d->base = (uint16_t)(0x100u + 0x20u * drive_id);
    return IP_OK;
}

int ip_can_decode(ip_can_decoder_t *d, const ip_can_frame_t *f, ip_message_t *m) {
    static const uint8_t dlc_of[13] = {8, 1, 4, 0, 0, 0, 0, 0, 8, 8, 8, 8, 8};
    if (f->id < d->base || f->id > d->base + IP_CAN_HELLO_C) return IP_ERR_TYPE;
    unsigned offset = (unsigned)(f->id - d->base);
    if (dlc_of[offset] == 0) return IP_ERR_TYPE;
    if (f->dlc != dlc_of[offset]) return IP_ERR_FRAMING;
    const uint8_t *p = f->data;
    switch (offset) {
    case IP_CAN_TELEMETRY_B:
        d->u_dc = get16(p + 2); d->encoder = get16(p + 4); d->status = get16(p + 6);
        return 0;
    case IP_CAN_TELEMETRY_A:
        d->last_seq = ip_unwrap16(get16(p), d->last_seq);
        m->type = IP_TELEMETRY;
        m->u.telemetry.seq = d->last_seq; m->u.telemetry.i_a = (int16_t)get16(p + 2);
        m->u.telemetry.i_b = (int16_t)get16(p + 4); m->u.telemetry.i_c = (int16_t)get16(p + 6);
        m->u.telemetry.u_dc = d->u_dc; m->u.telemetry.encoder = d->encoder; m->u.telemetry.status = d->status;
        return 1;
    case IP_CAN_COMMAND:
        d->last_seq = ip_unwrap16(get16(p), d->last_seq);
        m->type = IP_COMMAND;
        m->u.command.seq = d->last_seq; m->u.command.u_alpha = (int16_t)get16(p + 2);
        m->u.command.u_beta = (int16_t)get16(p + 4); m->u.command.flags = p[6];
        return 1;
    case IP_CAN_CONTROL:
        m->type = IP_CONTROL; m->u.control.action = p[0];
        return 1;
    case IP_CAN_HEARTBEAT:
        m->type = IP_HEARTBEAT; m->u.heartbeat.counter = get32(p);
        return 1;
    default: {
        unsigned slot = offset - IP_CAN_HELLO_A;
        memcpy(d->hello[slot], p, 8);
        d->hello_seen |= (uint8_t)(1u << slot);
        if (d->hello_seen != 7u) return 0;
        d->hello_seen = 0;
        if (d->hello[0][0] != IP_VERSION) return IP_ERR_VERSION;
        ip_hello_t *h = &m->u.hello;
        m->type = IP_HELLO;
        h->drive_id = d->hello[0][1]; h->flags = d->hello[0][2]; h->n_p = d->hello[0][3];
        h->T_s_ns = get32(d->hello[0] + 4); h->current_lsb_A = getf(d->hello[1]);
        h->voltage_lsb_V = getf(d->hello[1] + 4); h->trip_current_A = getf(d->hello[2]);
        h->watchdog_periods = get16(d->hello[2] + 4); h->block_samples = d->hello[2][6];
        return 1;
    }
    }
}

static uint8_t canfd_length(size_t n) {
    static const uint8_t lengths[] = {12, 16, 20, 24, 32, 48, 64};
    if (n <= 8) return (uint8_t)n;
    for (size_t i = 0; i < sizeof lengths; i++)
        if (n <= lengths[i]) return lengths[i];
    return 0;
}

size_t ip_canfd_encode(const ip_message_t *m, uint8_t drive_id, ip_canfd_frame_t frames[IP_CANFD_MAX_FRAMES]) {
    if (drive_id > 15 || (m->type != IP_TELEMETRY_BLOCK && m->type != IP_COMMAND_BLOCK)) return 0;
    unsigned count = count_of(m);
    if (count < 1u || count > IP_MAX_BLOCK) return 0;
    int telemetry = m->type == IP_TELEMETRY_BLOCK;
    unsigned chunk = telemetry ? IP_CANFD_TELEMETRY_SAMPLES : IP_CANFD_COMMAND_SAMPLES;
    uint16_t id = (uint16_t)(0x100u + 0x20u * drive_id + (telemetry ? IP_CAN_TELEMETRY_BLOCK : IP_CAN_COMMAND_BLOCK));
    size_t n = 0;
    for (unsigned start = 0; start < count; start += chunk, n++) {
        unsigned k = count - start < chunk ? count - start : chunk;
        ip_message_t part = *m;
        if (telemetry) {
            part.u.telemetry_block.seq += start;
            part.u.telemetry_block.count = (uint8_t)k;
            memmove(part.u.telemetry_block.s, m->u.telemetry_block.s + start, k * sizeof part.u.telemetry_block.s[0]);
        } else {
            part.u.command_block.seq += start;
            part.u.command_block.count = (uint8_t)k;
            memmove(part.u.command_block.s, m->u.command_block.s + start, k * sizeof part.u.command_block.s[0]);
        }
        frames[n].id = id;
        frames[n].len = canfd_length(body_size(m->type, k));
        memset(frames[n].data, 0, sizeof frames[n].data);
        pack_body(&part, frames[n].data);
    }
    return n;
}

int ip_canfd_decode(uint8_t drive_id, const ip_canfd_frame_t *f, ip_message_t *m) {
    if (drive_id > 15) return IP_ERR_TYPE;
    unsigned offset = (unsigned)f->id - (0x100u + 0x20u * drive_id);
    uint8_t type;
    unsigned head, chunk;
    if (offset == IP_CAN_TELEMETRY_BLOCK) { type = IP_TELEMETRY_BLOCK; head = 9; chunk = IP_CANFD_TELEMETRY_SAMPLES; }
    else if (offset == IP_CAN_COMMAND_BLOCK) { type = IP_COMMAND_BLOCK; head = 6; chunk = IP_CANFD_COMMAND_SAMPLES; }
    else return IP_ERR_TYPE;
    if (f->len > sizeof f->data || f->len < head) return IP_ERR_FRAMING;
    unsigned count = f->data[head - 1];
    if (count < 1u || count > chunk || body_size(type, count) > f->len) return IP_ERR_FRAMING;
    unpack_body(type, f->data, m);
    return IP_OK;
}
