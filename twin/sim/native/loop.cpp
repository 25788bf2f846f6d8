// The twin's stepping loops in C++, for the steps where nothing needs Python.
//
// bl_plant_run is twin.sim.plant.Plant.step: chunks of physics steps up to the next sensor
// sample, the engagement check and its short steps, the load cells and the tracker.
// bl_run is what twin.device.sim_transport does per 5 ms board tick: the firmware's tick, its
// motor outputs into the plant, then the plant's step as above.
//
// Both return to Python, at the exact point where the Python path would do it, whenever it has
// work: bytes for the host, a drive the plant must switch mode for, a MuJoCo warning, the
// keepalive, the deadline, or the sensor noise buffer running low. Run to run they take the
// same steps with the same numbers as the Python path (tests/test_board_loop.py and
// tests/test_sim_native.py check them bit for bit): the same float operations in the same order.
//
// No link-time dependency: the firmware's tick and mj_step come in as function pointers from
// the libraries Python has already loaded; MuJoCo's headers give the mjModel/mjData layout.
//
// Build: twin.sim.native_loop.build_library() (g++ -O2 -ffp-contract=off -shared -fPIC
// -I<mujoco>/include).

#include <math.h>
#include <stddef.h>
#include <stdint.h>

#include <mujoco/mujoco.h>

#define BL_ABI_VERSION 6
#define BL_CHANNELS 4
// Normal draws a tick can take: four load cells, then six position and six axis components of
// the tracker's two probes.
#define BL_NOISE_PER_TICK 16

extern "C" {

typedef void (*bl_tick_fn)(void* fw, uint64_t now_us, const int32_t* encoder_counts, const int32_t* raw_counts,
                           uint32_t new_sample_mask, float* duty_out, uint8_t* drive_out);
typedef void (*bl_step_fn)(const mjModel* m, mjData* d);
typedef size_t (*bl_pending_fn)(const void* fw);

// Why bl_run returned; the tick's state is then exactly what the Python path has at that point.
enum bl_reason {
  BL_DEADLINE = 0,    // time reached the deadline before a tick: wait_until returns False
  BL_KEEPALIVE = 1,   // a keepalive PING is due before the next tick: Python runs the tick
  BL_APPLY = 2,       // ticked; the outputs need Python (coast, or the plant not in PWM mode)
  BL_TX = 3,          // ticked and applied; bytes for the host: deliver, then resume
  BL_WARNING = 4,     // stepped; MuJoCo raised a warning (Python raises it, then samples)
  BL_NOISE = 5,       // before a tick: too few noise draws left; Python refills the buffer
  BL_DONE = 6,        // bl_run: resumed at the advance of a tick and stepped: the tick is
                      // complete; bl_plant_run: all the steps are taken
};

// Shared with Python (twin.device.board_loop._State): inputs, state carried across calls,
// and outputs. Pointers and doubles first, then 32-bit fields, then bytes, so ctypes lays it
// out the same.
struct bl_state {
  double* noise;               // the sensors' standard normal draws (twin.sim.sensors.NoiseStream)
  // inputs (constant for a plant and board)
  double m_per_count;          // tendon per encoder count (m)
  double engage_stretch_m;     // a tendon stretched less than this gets the engagement check
  double engage_speed_m_s;     // closing speed at which a full step's spike is too large
  double supply_voltage_v;
  double stall_force_n;
  double reflected_mass_kg;
  double tick_s;
  double tendon_stiffness_n_per_m;
  double loadcell_gain_counts_per_n;
  double loadcell_noise_n;     // RMS (N)
  double loadcell_rate_hz;
  double tracker_noise_m;      // RMS per axis (m)
  double tracker_noise_rad;    // RMS per axis component (rad)
  double tracker_rate_hz;
  double slack_length_m[BL_CHANNELS];
  double loadcell_offset_counts[BL_CHANNELS];
  double loadcell_gain_error[BL_CHANNELS];
  double loadcell_offset_error_n[BL_CHANNELS];
  double probe_position_m[6];  // probes A and B in the tip frame (m)
  double probe_axis[6];        // their unit axes in the tip frame
  // inputs refreshed by Python before each call
  double power_up_s;           // plant time of the firmware's power-up (s)
  double deadline_s;           // board time at which wait_until gives up (s)
  double last_write_s;         // board time of the host's last write (s)
  double keepalive_s;          // keepalive period (s); +inf for none
  // carried across calls (Python reads and writes them)
  double next_loadcell_s;      // plant time of the next load-cell sample (s)
  double next_tracker_s;       // plant time of the next tracker frame (s)
  double loadcell_time_s;      // out: plant time of the latest load-cell sample (s)
  double tracker_time_s;       // out: plant time of the latest tracker frame (s)
  double tracker_positions_m[6];  // out: the latest frame's probe positions, world (m)
  double tracker_axes[6];         // out: and unit axes
  double pwm_v[BL_CHANNELS];   // voltages last given to the plant's motors
  double jump_accel_m_s2;      // spool acceleration step since the last physics step
  int32_t noise_size;          // draws in the buffer
  int32_t noise_cursor;        // the next draw to take
  int32_t tip_site;
  int32_t engage_substeps;     // steps a tick is cut into while a tendon could engage
  int32_t current_substeps;    // what mjModel.opt.timestep is cut to now
  int32_t jump;                // 1 after a change the engagement check cannot bound
  int32_t short_steps;         // out: steps taken as short ones in the call
  int32_t spool_qpos[BL_CHANNELS];
  int32_t pwm_ctrl[BL_CHANNELS];
  int32_t raw_counts[BL_CHANNELS];
  int32_t loadcell_index;      // index of the plant's current load-cell sample
  int32_t last_loadcell_index; // the board's: the sample the firmware has seen
  int32_t tracker_index;       // index of the plant's current tracker frame
  int32_t warnings_total;      // sum of the warning counters the plant has seen
  int32_t plant_pwm;           // 1 while the plant is in PWM mode
  int32_t held;                // 1 while the fixture holds the tensions (outputs ignored)
  int32_t have_applied;        // 1 when applied_duty/applied_drive are what the plant has
  int32_t ticks;               // out: ticks (bl_run) or steps (bl_plant_run) taken in the call
  int32_t applied_changed;     // out: 1 when the call gave the plant new motor outputs
  int32_t resume;              // in: 1 to start at the advance of a tick Python delivered for
  float applied_duty[BL_CHANNELS];
  float duty[BL_CHANNELS];     // out: the last tick's outputs
  uint8_t applied_drive[BL_CHANNELS];
  uint8_t drive[BL_CHANNELS];
};

uint32_t bl_abi_version(void) { return BL_ABI_VERSION; }
uint32_t bl_state_size(void) { return (uint32_t)sizeof(bl_state); }

// Python's max(x, 0.0): x unless 0.0 is larger.
static inline double py_max0(double x) { return 0.0 > x ? 0.0 : x; }

static int warnings_total(const mjData* d) {
  int total = 0;
  for (int i = 0; i < mjNWARNING; ++i) total += d->warning[i].number;
  return total;
}

static bool same_outputs(const bl_state* s) {
  if (!s->have_applied) return false;
  for (int i = 0; i < BL_CHANNELS; ++i) {
    // Bytewise, as the Python path compares duty.tobytes().
    uint32_t a, b;
    __builtin_memcpy(&a, &s->duty[i], 4);
    __builtin_memcpy(&b, &s->applied_duty[i], 4);
    if (a != b || s->drive[i] != s->applied_drive[i]) return false;
  }
  return true;
}

// The PWM drive of twin.sim.plant.Plant.set_motor_pwm with twin.device.board's duty choice.
static void apply_pwm(mjData* d, bl_state* s) {
  double volts[BL_CHANNELS];
  double largest = 0.0;
  for (int i = 0; i < BL_CHANNELS; ++i) {
    double x = s->drive[i] == 1 ? (double)s->duty[i] : 0.0;
    x = fmin(fmax(x, -1.0), 1.0) * s->supply_voltage_v;
    volts[i] = x;
    double change = fabs(x - s->pwm_v[i]);
    if (change > largest) largest = change;
  }
  double step_n = s->stall_force_n / s->supply_voltage_v * largest;
  s->jump_accel_m_s2 += step_n / s->reflected_mass_kg;
  for (int i = 0; i < BL_CHANNELS; ++i) {
    s->pwm_v[i] = volts[i];
    d->ctrl[s->pwm_ctrl[i]] = volts[i];
  }
}

// Plant._engage_risk for a chunk of ``chunk`` steps, with the same float operations in the same order.
static bool engage_risk(const mjModel* m, const mjData* d, const bl_state* s, int chunk) {
  double span = chunk * s->tick_s + s->tick_s;
  for (int i = 0; i < BL_CHANNELS; ++i) {
    double stretch = d->ten_length[i] - s->slack_length_m[i];
    if (!(stretch < s->engage_stretch_m)) continue;
    // After a change it cannot bound, any tendon near slack counts.
    if (s->jump) return true;
    double acc = 0.0;
    int start = m->ten_J_rowadr[i], end = start + m->ten_J_rownnz[i];
    for (int k = start; k < end; ++k) acc += d->ten_J[k] * d->qacc[m->ten_J_colind[k]];
    double a = py_max0(acc) + s->jump_accel_m_s2;
    double v = py_max0(d->ten_velocity[i]);
    if (v + a * span > s->engage_speed_m_s && stretch + (v + 0.5 * a * span) * span > 0.0) return true;
  }
  return false;
}

// twin.sim.sensors.LoadCells.read of Plant.true_tensions_n.
static void sample_loadcells(const mjData* d, bl_state* s) {
  const double* z = s->loadcell_noise_n > 0 ? s->noise + s->noise_cursor : nullptr;
  if (z) s->noise_cursor += BL_CHANNELS;
  for (int i = 0; i < BL_CHANNELS; ++i) {
    double tension = py_max0(d->ten_length[i] - s->slack_length_m[i]) * s->tendon_stiffness_n_per_m;
    double sensed = (1.0 + s->loadcell_gain_error[i]) * tension + s->loadcell_offset_error_n[i];
    if (z) sensed = sensed + s->loadcell_noise_n * z[i];
    // Python's round(): to nearest, ties to even (the default rounding mode).
    double code = nearbyint(s->loadcell_offset_counts[i] + s->loadcell_gain_counts_per_n * sensed);
    s->raw_counts[i] = (int32_t)fmin(fmax(code, -8388608.0), 8388607.0);
  }
  s->loadcell_index += 1;
  s->loadcell_time_s = d->time;
  s->next_loadcell_s = (double)(s->loadcell_index + 1) / s->loadcell_rate_hz;
}

// twin.sim.sensors.Tracker.read of Plant.tip_pose.
static void sample_tracker(const mjData* d, bl_state* s) {
  const double* p = d->site_xpos + 3 * s->tip_site;
  const double* r = d->site_xmat + 9 * s->tip_site;
  double noise_m[6] = {0, 0, 0, 0, 0, 0}, noise_rad[6];
  if (s->tracker_noise_m > 0) {
    for (int j = 0; j < 6; ++j) noise_m[j] = s->tracker_noise_m * s->noise[s->noise_cursor + j];
    s->noise_cursor += 6;
  }
  bool turn = s->tracker_noise_rad > 0;
  if (turn) {
    for (int j = 0; j < 6; ++j) noise_rad[j] = s->tracker_noise_rad * s->noise[s->noise_cursor + j];
    s->noise_cursor += 6;
  }
  for (int k = 0; k < 2; ++k) {
    const double* x = s->probe_position_m + 3 * k;
    const double* u = s->probe_axis + 3 * k;
    for (int j = 0; j < 3; ++j) {
      s->tracker_positions_m[3 * k + j] = p[j] + r[3 * j] * x[0] + r[3 * j + 1] * x[1] + r[3 * j + 2] * x[2]
                                          + noise_m[3 * k + j];
    }
    double a0 = r[0] * u[0] + r[1] * u[1] + r[2] * u[2];
    double a1 = r[3] * u[0] + r[4] * u[1] + r[5] * u[2];
    double a2 = r[6] * u[0] + r[7] * u[1] + r[8] * u[2];
    if (turn) {
      // Small-angle rotation of the axis: a + w × a, then renormalised.
      const double* w = noise_rad + 3 * k;
      double b0 = a0 + w[1] * a2 - w[2] * a1, b1 = a1 + w[2] * a0 - w[0] * a2, b2 = a2 + w[0] * a1 - w[1] * a0;
      double norm = sqrt(b0 * b0 + b1 * b1 + b2 * b2);
      a0 = b0 / norm, a1 = b1 / norm, a2 = b2 / norm;
    }
    s->tracker_axes[3 * k] = a0;
    s->tracker_axes[3 * k + 1] = a1;
    s->tracker_axes[3 * k + 2] = a2;
  }
  s->tracker_index += 1;
  s->tracker_time_s = d->time;
  s->next_tracker_s = (double)(s->tracker_index + 1) / s->tracker_rate_hz;
}

// One chunk of Plant.step: ``chunk`` physics steps (as shorter ones where the engagement check
// asks), then Plant._end_chunk (warning check, due samples). Returns 0, or BL_WARNING before
// sampling.
static int plant_chunk(mjModel* m, mjData* d, bl_step_fn step, bl_state* s, int chunk) {
  int substeps = 1;
  if (s->engage_substeps > 1 && engage_risk(m, d, s, chunk)) {
    substeps = s->engage_substeps;
    s->short_steps += chunk;
  }
  s->jump = 0;
  s->jump_accel_m_s2 = 0.0;
  if (substeps != s->current_substeps) {
    m->opt.timestep = s->tick_s / substeps;
    s->current_substeps = substeps;
  }
  for (int k = 0; k < chunk * substeps; ++k) step(m, d);
  if (warnings_total(d) != s->warnings_total) return BL_WARNING;
  if (d->time >= s->next_loadcell_s - 1e-9) sample_loadcells(d, s);
  if (d->time >= s->next_tracker_s - 1e-9) sample_tracker(d, s);
  return 0;
}

// Plant.step(steps · tick_s) without friction: chunks up to the next sensor sample.
int bl_plant_run(mjModel* m, mjData* d, bl_step_fn step, bl_state* s, int32_t steps) {
  s->ticks = 0;
  s->short_steps = 0;
  while (s->ticks < steps) {
    if (s->noise_size - s->noise_cursor < BL_NOISE_PER_TICK) return BL_NOISE;
    // Plant._steps_until(min(next load-cell sample, next tracker frame))
    double next_s = s->next_tracker_s < s->next_loadcell_s ? s->next_tracker_s : s->next_loadcell_s;
    int until = (int)ceil((next_s - d->time) / s->tick_s - 1e-9);
    int chunk = steps - s->ticks;
    if (until < 1) until = 1;
    if (until < chunk) chunk = until;
    s->ticks += chunk;
    int reason = plant_chunk(m, d, step, s, chunk);
    if (reason) return reason;
  }
  return BL_DONE;
}

int bl_run(mjModel* m, mjData* d, void* fw, bl_tick_fn tick, bl_pending_fn pending, bl_step_fn step,
           bl_state* s, int32_t max_ticks) {
  s->ticks = 0;
  s->applied_changed = 0;
  s->short_steps = 0;
  bool resume = s->resume != 0;
  s->resume = 0;
  while (s->ticks < max_ticks) {
    if (resume) goto advance;
    {
    double board_s = d->time - s->power_up_s;
    if (board_s >= s->deadline_s) return BL_DEADLINE;
    // The same expression as SimTransport._step, so the PING falls on the same tick.
    if (board_s - s->last_write_s >= s->keepalive_s - 1e-9) return BL_KEEPALIVE;
    if (s->noise_size - s->noise_cursor < BL_NOISE_PER_TICK) return BL_NOISE;
    // EmulatedBoard.tick
    int32_t counts[BL_CHANNELS];
    for (int i = 0; i < BL_CHANNELS; ++i) {
      counts[i] = (int32_t)floor(d->qpos[s->spool_qpos[i]] / s->m_per_count + 1e-9);
    }
    uint32_t mask = s->loadcell_index != s->last_loadcell_index ? 0xFu : 0u;
    s->last_loadcell_index = s->loadcell_index;
    tick(fw, (uint64_t)nearbyint(board_s * 1e6), counts, s->raw_counts, mask, s->duty, s->drive);
    s->ticks += 1;
    // EmulatedBoard._apply
    if (s->held) {
      s->applied_changed |= s->have_applied;
      s->have_applied = 0;
    } else if (!same_outputs(s)) {
      bool coast = true;
      for (int i = 0; i < BL_CHANNELS; ++i) coast = coast && s->drive[i] == 0;
      if (coast || !s->plant_pwm) return BL_APPLY;
      apply_pwm(d, s);
      for (int i = 0; i < BL_CHANNELS; ++i) {
        s->applied_duty[i] = s->duty[i];
        s->applied_drive[i] = s->drive[i];
      }
      s->have_applied = 1;
      s->applied_changed = 1;
    }
    if (pending(fw) > 0) return BL_TX;
    }
  advance:
    {
    // EmulatedBoard.advance: Plant.step(TICK_S), one chunk of one step.
    int reason = plant_chunk(m, d, step, s, 1);
    if (reason) return reason;
    // After a delivery the wait's predicate must be looked at before the next tick.
    if (resume) return BL_DONE;
    }
  }
  return BL_DEADLINE;
}

}  // extern "C"
