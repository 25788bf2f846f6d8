/* C API over the firmware core for host programs (the emulated board, tests): a Firmware
 * object stepped with explicit time, and a standalone frame decoder for fuzzing the C++ codec.
 * Arrays have as many entries as the board has channels (at most TWINFW_MAX_CHANNELS). Not
 * thread-safe: one caller per object. */
#ifndef TWINFW_H
#define TWINFW_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define TWINFW_ABI_VERSION 4
#define TWINFW_MAX_CHANNELS 12

typedef struct twinfw_board twinfw_board;
typedef struct twinfw_decoder twinfw_decoder;

/* TWINFW_ABI_VERSION of the built library; callers refuse a mismatch. */
uint32_t twinfw_abi_version(void);
/* Protocol version the firmware speaks (firmware/PROTOCOL.md). */
uint32_t twinfw_protocol_version(void);

/* TWINFW_MAX_CHANNELS of the built library. */
uint32_t twinfw_max_channels(void);

/* A fresh board of `channels` motors and load cells as after power-up; NULL if out of memory
 * or channels is outside 1..TWINFW_MAX_CHANNELS. */
twinfw_board* twinfw_create(uint32_t channels);
/* The same for a rig whose encoders count tendon_m_per_count metres of tendon each (its spool,
 * gearbox and encoder: the emulated board of another robot); NULL also if that is not finite
 * and positive. twinfw_create takes the thesis rig's (firmware/core/config.h). */
twinfw_board* twinfw_create_rig(uint32_t channels, float tendon_m_per_count);
/* The channel count the board was created with. */
uint32_t twinfw_channels(const twinfw_board* fw);
void twinfw_destroy(twinfw_board* fw);

/* Host bytes, any chunking; commands are acted on at the time of the latest tick. */
void twinfw_receive(twinfw_board* fw, const uint8_t* data, size_t size);

/* One step at now_us (µs, any origin, non-decreasing). new_sample_mask bit i marks
 * raw_counts[i] as a fresh HX711 sample. Writes duty_out in [-1, 1] and drive_out
 * (0 coast, 1 drive, 2 brake). */
void twinfw_tick(twinfw_board* fw, uint64_t now_us, const int32_t* encoder_counts, const int32_t* raw_counts,
                 uint32_t new_sample_mask, float* duty_out, uint8_t* drive_out);

/* Bytes queued for the host. */
size_t twinfw_tx_pending(const twinfw_board* fw);
/* Moves up to capacity queued bytes into out; returns how many. */
size_t twinfw_take_tx(twinfw_board* fw, uint8_t* out, size_t capacity);

twinfw_decoder* twinfw_decoder_create(void);
void twinfw_decoder_destroy(twinfw_decoder* decoder);
/* Feeds bytes; each frame that passes COBS and CRC is written to out as one record
 * [length u16 LE][type u8][seq u16 LE][payload] (length: the bytes after it), records back to back. Returns the bytes written;
 * a record that does not fit in capacity is dropped and counted in twinfw_decoder_overflows. */
size_t twinfw_decoder_feed(twinfw_decoder* decoder, const uint8_t* data, size_t size, uint8_t* out,
                           size_t capacity);
/* Frames rejected for framing or CRC errors so far. */
uint32_t twinfw_decoder_bad_frames(const twinfw_decoder* decoder);
uint32_t twinfw_decoder_overflows(const twinfw_decoder* decoder);

#ifdef __cplusplus
}
#endif

#endif
