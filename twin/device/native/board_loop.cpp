// The emulated board's tick loop in C++: what twin.device.sim_transport does per 5 ms tick
// (firmware tick, motor outputs into the plant, one MuJoCo step), for the ticks where nothing
// needs Python. It returns to Python, at the exact point of the tick where the Python path
// would do it, whenever something does: bytes for the host, a sensor sample due, a drive the
// plant must switch mode for, a tendon near slack (the plant's engagement check), a MuJoCo
// warning, the keepalive, the deadline. Run to run it takes the same steps with the same
// numbers as the Python path (tests/test_board_loop.py checks them bit for bit).
//
// No link-time dependency: the firmware's tick and mj_step come in as function pointers from
// the libraries Python has already loaded; MuJoCo's headers give the mjModel/mjData layout.
//
// Build: twin.device.board_loop.build_library() (g++ -O2 -shared -fPIC -I<mujoco>/include).

#include <math.h>
#include <stddef.h>
#include <stdint.h>

#include <mujoco/mujoco.h>

#define BL_ABI_VERSION 4
#define BL_CHANNELS 4

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
  BL_TX = 3,          // ticked and applied; bytes for the host: deliver, then advance
  BL_ADVANCE = 4,     // ticked, applied, nothing to deliver; the plant step needs Python
  BL_WARNING = 5,     // stepped; MuJoCo raised a warning
  BL_SAMPLE = 6,      // stepped; a load-cell or tracker sample is due
  BL_DONE = 7,        // resumed at the advance of a tick and stepped: the tick is complete
};

// Shared with Python (twin.device.board_loop._State): inputs, state carried across calls,
// and outputs. Doubles first, then 32-bit fields, then bytes, so ctypes lays it out the same.
struct bl_state {
  // inputs (constant for a plant and board)
  double m_per_count;          // tendon per encoder count (m)
  double engage_stretch_m;     // a tendon stretched less than this gets the engagement check
  double engage_speed_m_s;     // closing speed at which a full step's spike is too large
  double supply_voltage_v;
  double stall_force_n;
  double reflected_mass_kg;
  double tick_s;
  // inputs refreshed by Python before each call
  double power_up_s;           // plant time of the firmware's power-up (s)
  double next_sample_s;        // plant time of the next load-cell or tracker sample (s)
  double deadline_s;           // board time at which wait_until gives up (s)
  double last_write_s;         // board time of the host's last write (s)
  double keepalive_s;          // keepalive period (s); +inf for none
  double slack_length_m[BL_CHANNELS];
  // carried across calls (Python reads and writes them)
  double pwm_v[BL_CHANNELS];   // voltages last given to the plant's motors
  double jump_accel_m_s2;      // spool acceleration step since the last physics step
  int32_t spool_qpos[BL_CHANNELS];
  int32_t pwm_ctrl[BL_CHANNELS];
  int32_t raw_counts[BL_CHANNELS];
  int32_t loadcell_index;      // index of the plant's current load-cell sample
  int32_t last_loadcell_index; // the board's: the sample the firmware has seen
  int32_t warnings_total;      // sum of the warning counters the plant has seen
  int32_t plant_pwm;           // 1 while the plant is in PWM mode
  int32_t held;                // 1 while the fixture holds the tensions (outputs ignored)
  int32_t have_applied;        // 1 when applied_duty/applied_drive are what the plant has
  int32_t ticks;               // out: ticks run in the call
  int32_t applied_changed;     // out: 1 when the call gave the plant new motor outputs
  int32_t resume;              // in: 1 to start at the advance of a tick Python delivered for
  float applied_duty[BL_CHANNELS];
  float duty[BL_CHANNELS];     // out: the last tick's outputs
  uint8_t applied_drive[BL_CHANNELS];
  uint8_t drive[BL_CHANNELS];
};

uint32_t bl_abi_version(void) { return BL_ABI_VERSION; }
uint32_t bl_state_size(void) { return (uint32_t)sizeof(bl_state); }

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
static void apply_pwm(const mjModel* m, mjData* d, bl_state* s) {
  (void)m;
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

// Plant._engage_risk for a chunk of one step, with the same float operations in the same order.
static bool engage_risk(const mjModel* m, const mjData* d, const bl_state* s) {
  double span = s->tick_s + s->tick_s;
  for (int i = 0; i < BL_CHANNELS; ++i) {
    double stretch = d->ten_length[i] - s->slack_length_m[i];
    if (!(stretch < s->engage_stretch_m)) continue;
    double acc = 0.0;
    int start = m->ten_J_rowadr[i], end = start + m->ten_J_rownnz[i];
    for (int k = start; k < end; ++k) acc += d->ten_J[k] * d->qacc[m->ten_J_colind[k]];
    // Python's max(x, 0.0): x unless 0.0 is larger.
    double a = (0.0 > acc ? 0.0 : acc) + s->jump_accel_m_s2;
    double v = 0.0 > d->ten_velocity[i] ? 0.0 : d->ten_velocity[i];
    if (v + a * span > s->engage_speed_m_s && stretch + (v + 0.5 * a * span) * span > 0.0) return true;
  }
  return false;
}

int bl_run(const mjModel* m, mjData* d, void* fw, bl_tick_fn tick, bl_pending_fn pending, bl_step_fn step,
           bl_state* s, int32_t max_ticks) {
  s->ticks = 0;
  s->applied_changed = 0;
  bool resume = s->resume != 0;
  s->resume = 0;
  while (s->ticks < max_ticks) {
    if (resume) goto advance;
    {
    double board_s = d->time - s->power_up_s;
    if (board_s >= s->deadline_s) return BL_DEADLINE;
    // The same expression as SimTransport._step, so the PING falls on the same tick.
    if (board_s - s->last_write_s >= s->keepalive_s - 1e-9) return BL_KEEPALIVE;
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
      apply_pwm(m, d, s);
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
    // EmulatedBoard.advance: Plant.step(TICK_S), one physics step; when the engagement check
    // asks for short steps, Python takes them.
    if (engage_risk(m, d, s)) return BL_ADVANCE;
    step(m, d);
    s->jump_accel_m_s2 = 0.0;
    int total = warnings_total(d);
    if (total != s->warnings_total) return BL_WARNING;
    if (d->time >= s->next_sample_s - 1e-9) return BL_SAMPLE;
    // After a delivery the wait's predicate must be looked at before the next tick.
    if (resume) return BL_DONE;
  }
  return BL_DEADLINE;
}

}  // extern "C"
