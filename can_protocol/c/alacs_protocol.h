/*
 * ALACS CAN protocol: the parts the generated codec (generated/alacs.h) does not
 * know: node-id offsets and the command checksum. Header-only, C11 and C++,
 * no I/O. Kept in step with can_protocol/python/src/alacs_can/constants.py by
 * can_protocol/python/tests/test_c_codec.py.
 */
#ifndef ALACS_PROTOCOL_H
#define ALACS_PROTOCOL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
/* C casts in C code: not C++'s old-style casts (-Wold-style-cast) when C++ includes this. */
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wold-style-cast"
#endif

#define ALACS_PROTOCOL_VERSION (2u)
#define ALACS_DEFAULT_NODE_ID (0x10u)
#define ALACS_NODE_ID_MIN (1u)
#define ALACS_NODE_ID_MAX (127u)

/* CANopen-style base ids; frame id = base + node id (except NMT, fixed 0x000).
 * The *_FRAME_ID macros in generated/alacs.h are for node id 0x10 only. */
#define ALACS_BASE_ID_NMT (0x000u)
#define ALACS_BASE_ID_EMCY (0x080u)
#define ALACS_BASE_ID_ACK (0x180u)
#define ALACS_BASE_ID_COMMAND (0x200u)
#define ALACS_BASE_ID_RESULT_HEADER (0x280u)
#define ALACS_BASE_ID_RESULT_OBJECT (0x380u)
#define ALACS_BASE_ID_STATUS (0x480u)
#define ALACS_BASE_ID_SDO_TX (0x580u)
#define ALACS_BASE_ID_SDO_RX (0x600u)
#define ALACS_BASE_ID_PROGRESS (0x680u)
#define ALACS_BASE_ID_HEARTBEAT (0x700u)

#define ALACS_COMMAND_DLC (8u)
#define ALACS_COMMAND_CHECKSUM_BYTE (7u)

/* Frame id of a node-offset message for node_id (1..127); the caller validates node_id. */
static inline uint32_t alacs_frame_id(uint32_t base_id, uint8_t node_id)
{
    return base_id + (uint32_t)node_id;
}

/* CRC-8/SAE-J1850: poly 0x1D, init 0xFF, not reflected, xorout 0xFF.
 * alacs_crc8_j1850("123456789", 9) == 0x4B. */
static inline uint8_t alacs_crc8_j1850(const uint8_t *data, size_t len)
{
    uint8_t crc = 0xFFu;
    for (size_t i = 0u; i < len; ++i) {
        crc = (uint8_t)(crc ^ data[i]);
        for (unsigned bit = 0u; bit < 8u; ++bit) {
            crc = (uint8_t)(((crc & 0x80u) != 0u) ? ((unsigned)crc << 1u) ^ 0x1Du
                                                   : ((unsigned)crc << 1u));
        }
    }
    return (uint8_t)(crc ^ 0xFFu);
}

/* CmdChecksum for an 8-byte ALACS_Command: CRC over bytes 0..6. */
static inline uint8_t alacs_command_checksum(const uint8_t data[8])
{
    return alacs_crc8_j1850(data, ALACS_COMMAND_CHECKSUM_BYTE);
}

/* True if the command frame has DLC 8 and a correct byte-7 checksum. */
static inline bool alacs_command_checksum_ok(const uint8_t *data, size_t dlc)
{
    return dlc == ALACS_COMMAND_DLC &&
           alacs_command_checksum(data) == data[ALACS_COMMAND_CHECKSUM_BYTE];
}

#ifdef __cplusplus
#pragma GCC diagnostic pop
}
#endif

#endif /* ALACS_PROTOCOL_H */
