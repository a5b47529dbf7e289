/* Inverter wire protocol, version 2 (docs/inverter-protocol.md): message structs (per sample, and blocks
 * of samples), the serial framing (COBS + CRC-16/CCITT-FALSE, 0x00-delimited), the classic-CAN mapping
 * and blocks on CAN FD. No allocation: every buffer is the caller's, sized by the constants below. */
#ifndef INVERTER_PROTOCOL_H
#define INVERTER_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#define IP_VERSION 2u
#define IP_MAX_BLOCK 30u                       /* samples in one TELEMETRY_BLOCK or COMMAND_BLOCK */
#define IP_MAX_FRAME 253u                      /* decoded: version, type, body, CRC (a full TELEMETRY_BLOCK) */
#define IP_MAX_WIRE (IP_MAX_FRAME + 2u)        /* COBS adds 1 byte per 254, plus the 0x00 */

enum ip_type { IP_TELEMETRY = 0x01, IP_HELLO = 0x02, IP_TELEMETRY_BLOCK = 0x03, IP_COMMAND = 0x10, IP_CONTROL = 0x11,
               IP_HEARTBEAT = 0x12, IP_COMMAND_BLOCK = 0x13 };
enum ip_control_action { IP_CONTROL_DISABLE = 1, IP_CONTROL_CLEAR_FAULTS = 2, IP_CONTROL_SEND_HELLO = 3 };
enum ip_status {
    IP_OVERCURRENT = 1u << 0, IP_WATCHDOG = 1u << 1, IP_PWM_OFF = 1u << 2, IP_COMMAND_MISSING = 1u << 3,
    IP_HEARTBEAT_LOST = 1u << 4, IP_BAD_FRAME = 1u << 5, IP_UNDERVOLTAGE = 1u << 6, IP_ENCODER_VALID = 1u << 7,
    IP_OVERVOLTAGE = 1u << 8, IP_FREEWHEELING = 1u << 9, IP_SHORT_CIRCUIT = 1u << 10
};
#define IP_ENABLE 0x01u
#define IP_SAFE_STATE_SHIFT 1u
#define IP_SAFE_STATE_MASK 0x06u /* COMMAND flags bits 1-2: the safe state asked for whenever PWM stops */
enum ip_safe_state { IP_SAFE_AUTO = 0, IP_SAFE_FREEWHEEL = 1, IP_SAFE_ASC = 2 };
#define IP_HELLO_ENCODER_PRESENT 0x01u
#define IP_HELLO_SAFE_STATES 0x02u /* the inverter takes the safe state of the flags, reports bits 8-10 */

enum ip_result { IP_OK = 0, IP_ERR_FRAMING = -1, IP_ERR_CRC = -2, IP_ERR_VERSION = -3, IP_ERR_TYPE = -4,
                 IP_ERR_SPACE = -5 };

typedef struct { uint32_t seq; int16_t i_a, i_b, i_c; uint16_t u_dc, encoder, status; } ip_telemetry_t;
typedef struct {
    uint8_t drive_id, flags, n_p, block_samples; uint32_t T_s_ns;
    float current_lsb_A, voltage_lsb_V, trip_current_A; uint16_t watchdog_periods;
} ip_hello_t;
typedef struct { uint32_t seq; int16_t u_alpha, u_beta; uint8_t flags; } ip_command_t;
/* Samples seq .. seq + count - 1 (count 1 .. IP_MAX_BLOCK); u_dc and status as at the last one. */
typedef struct {
    uint32_t seq; uint16_t u_dc, status; uint8_t count;
    struct { int16_t i_a, i_b, i_c; uint16_t encoder; } s[IP_MAX_BLOCK];
} ip_telemetry_block_t;
typedef struct {
    uint32_t seq; uint8_t flags, count;
    struct { int16_t u_alpha, u_beta; } s[IP_MAX_BLOCK];
} ip_command_block_t;
typedef struct { uint8_t action; } ip_control_t;
typedef struct { uint32_t counter; } ip_heartbeat_t;

typedef struct {
    uint8_t type; /* enum ip_type */
    union {
        ip_telemetry_t telemetry; ip_hello_t hello; ip_command_t command; ip_control_t control;
        ip_heartbeat_t heartbeat; ip_telemetry_block_t telemetry_block; ip_command_block_t command_block;
    } u;
} ip_message_t;

uint16_t ip_crc16(const uint8_t *data, size_t len);
/* The flags byte of a COMMAND or COMMAND_BLOCK: ENABLE and the safe state asked for. */
uint8_t ip_command_flags(int enable, enum ip_safe_state safe);
/* The safe state a command's flags ask for; the reserved value 3 reads as IP_SAFE_AUTO. */
enum ip_safe_state ip_requested_safe_state(uint8_t flags);
/* COBS: returns the encoded length (no delimiter), 0 if it does not fit in cap. */
size_t ip_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap);
/* Returns IP_OK with *out_len set, or IP_ERR_FRAMING / IP_ERR_SPACE. */
int ip_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len);

/* The wire bytes of a message, delimiter included: returns the length, 0 if cap is too small, the type
 * unknown or a block's count outside 1 .. IP_MAX_BLOCK. */
size_t ip_encode(const ip_message_t *m, uint8_t *wire, size_t cap);
/* One frame (the bytes between two delimiters) to a message: IP_OK or a negative ip_result. */
int ip_decode(const uint8_t *frame, size_t len, ip_message_t *m);

/* Byte-at-a-time receiver: returns 1 when byte completed a message (in *m), 0 when none yet, and a
 * negative ip_result when it completed a bad frame (dropped; the next 0x00 resynchronises). */
typedef struct { uint8_t buf[IP_MAX_WIRE]; size_t len; uint8_t overflow; } ip_reader_t;
void ip_reader_init(ip_reader_t *r);
int ip_reader_push(ip_reader_t *r, uint8_t byte, ip_message_t *m);

/* CAN (classic, 11-bit identifiers, base 0x100 + 0x20 * drive_id). */
typedef struct { uint16_t id; uint8_t dlc; uint8_t data[8]; } ip_can_frame_t;
enum { IP_CAN_COMMAND = 0x00, IP_CAN_CONTROL = 0x01, IP_CAN_HEARTBEAT = 0x02, IP_CAN_TELEMETRY_B = 0x08,
       IP_CAN_TELEMETRY_A = 0x09, IP_CAN_HELLO_A = 0x0A, IP_CAN_HELLO_B = 0x0B, IP_CAN_HELLO_C = 0x0C };
/* Frames of a message (TELEMETRY: B then A); returns their number (0: bad drive_id, or a type classic CAN
 * does not carry: blocks travel as CAN FD frames, ip_canfd_encode). */
size_t ip_can_encode(const ip_message_t *m, uint8_t drive_id, ip_can_frame_t frames[3]);
typedef struct {
    uint16_t base; uint32_t last_seq; uint16_t u_dc, encoder, status;
    uint8_t hello_seen; uint8_t hello[3][8];
} ip_can_decoder_t;
int ip_can_decoder_init(ip_can_decoder_t *d, uint8_t drive_id);
/* Returns 1 when the frame completed a message (in *m), 0 when not, negative on a bad frame. */
int ip_can_decode(ip_can_decoder_t *d, const ip_can_frame_t *f, ip_message_t *m);
uint32_t ip_unwrap16(uint16_t low, uint32_t last);

/* CAN FD (64-byte data; base + 0x03 COMMAND_BLOCK, base + 0x0D TELEMETRY_BLOCK): a block travels in
 * chunks of at most IP_CANFD_TELEMETRY_SAMPLES or IP_CANFD_COMMAND_SAMPLES samples, each the block message
 * of its own samples (the serial body: no version, type or CRC), zero-padded to a CAN FD length. */
#define IP_CANFD_TELEMETRY_SAMPLES 6u
#define IP_CANFD_COMMAND_SAMPLES 14u
#define IP_CANFD_MAX_FRAMES 5u /* IP_MAX_BLOCK / IP_CANFD_TELEMETRY_SAMPLES */
enum { IP_CAN_COMMAND_BLOCK = 0x03, IP_CAN_TELEMETRY_BLOCK = 0x0D };
typedef struct { uint16_t id; uint8_t len; uint8_t data[64]; } ip_canfd_frame_t;
/* Frames of a block message; returns their number (0: bad drive_id, not a block, or a count outside
 * 1 .. IP_MAX_BLOCK). */
size_t ip_canfd_encode(const ip_message_t *m, uint8_t drive_id, ip_canfd_frame_t frames[IP_CANFD_MAX_FRAMES]);
/* A CAN FD block frame to the block message of its samples: IP_OK, or a negative ip_result. */
int ip_canfd_decode(uint8_t drive_id, const ip_canfd_frame_t *f, ip_message_t *m);

#endif
