// The twin's plant loop: the one implementation of how the simulated rig is driven, stepped and
// sensed, and of the emulated board's 5 ms tick around the firmware core.
//
// twin.sim.plant.Plant and twin.device.board.EmulatedBoard are thin bindings on these functions
// (twin.sim.native_loop); they keep only what needs Python: building the model, the sensors'
// random draws (a numpy generator fills the noise buffer), per-step effect hooks, raising
// errors, and carrying bytes to the host. Each call returns a bl_reason saying what Python must
// do before calling again.
//
// No link-time dependency: mj_step and mj_forward, the firmware's tick and the
// per-step hook come in as function pointers from the libraries Python has already loaded;
// MuJoCo's headers give the mjModel/mjData layout.
//
// Build: twin.sim.native_loop.build_library() (g++ -O2 -ffp-contract=off -shared -fPIC
// -I<mujoco>/include). No fused multiply-adds: the sums round the same on every machine.

#include <math.h>
#include <stddef.h>
#include <stdint.h>

#include <mujoco/mujoco.h>

#define BL_ABI_VERSION 11
// Tendons (spools, motors, load cells) a plant can have.
#define BL_MAX_CHANNELS 12
// The tracker's two probes: three position and three axis components each.
#define BL_PROBE_VALUES 6
// Board ticks of motor outputs the actuation latency keeps (the newest included).
#define BL_DELAY_TICKS 40

extern "C" {

typedef void (*bl_tick_fn)(void* fw, uint64_t now_us, const int32_t* encoder_counts, const int32_t* raw_counts,
                           uint32_t new_sample_mask, float* duty_out, uint8_t* drive_out);
typedef size_t (*bl_pending_fn)(const void* fw);
typedef void (*bl_mj_fn)(const mjModel* m, mjData* d);
typedef void (*bl_hook_fn)(void);

// Why a call returned.
enum bl_reason {
  BL_DONE = 0,       // the steps (bl_plant_run) or ticks (bl_board_run) asked for are taken
  BL_DEADLINE = 1,   // bl_board_run: board time reached the deadline before a tick
  BL_KEEPALIVE = 2,  // bl_board_run: the host's keepalive PING is due before the next tick
  BL_TX = 3,         // bl_board_run: ticked, bytes for the host; deliver, then call with resume
  BL_WARNING = 4,    // MuJoCo raised a warning: the simulation diverged
  BL_NOISE = 5,      // too few noise draws left for the next step or tick; refill the buffer
};

// Drive modes of the spools (twin.sim.plant.MODES, in order).
enum bl_mode { BL_PWM = 0, BL_COAST = 1, BL_TENSION = 2, BL_LENGTH = 3 };

// The firmware's drive per motor (twin.driver.codec.Drive).
enum { BL_DRIVE_COAST = 0, BL_DRIVE_ON = 1 };

// The state shared with Python, declared once: twin.sim.native_loop builds its ctypes structure
// from bl_state_fields(), which lists these fields with their offsets. S(kind, name) is a scalar,
// A(kind, name, count) an array. Pointers and doubles first, then 32-bit fields, then bytes.
#define BL_STATE(S, A)                                                                                   \
  /* function pointers and buffers (set once per plant or power-up) */                                  \
  S(f64p, noise)                /* the sensors' standard normal draws (twin.sim.sensors.NoiseStream) */ \
  S(ptr, step_fn)               /* mj_step */                                                           \
  S(ptr, forward_fn)            /* mj_forward */                                                        \
  S(ptr, hook_fn)               /* called before every physics step when set (effects) */               \
  S(ptr, firmware)              /* the firmware core's handle */                                        \
  S(ptr, tick_fn)               /* the firmware's tick */                                               \
  S(ptr, pending_fn)            /* the firmware's count of bytes queued for the host */                 \
  S(f64p, geometry)             /* tendons' second-order length (twin.sim.model.GeometricStiffness) */  \
  S(ptr, geometry_index)        /* int32: its joints' ids and addresses */                              \
  S(ptr, friction_sites)        /* int32 (channels × friction_sites_per_tendon): each tendon's path */  \
  S(ptr, friction_joint_dofs)   /* int32 (channels × sites × 6): dofs in each site's plane (-1: none) */ \
  S(f64p, friction_joint_coefficients) /* ... and the tendon's length coefficient on each */            \
  /* plant constants */                                                                                 \
  S(f64, step_s)                /* physics step sim.timestep_s (s) */                                   \
  S(f64, engage_stretch_m)      /* a tendon stretched less than this gets the engagement check */       \
  S(f64, engage_speed_m_s)      /* closing speed at which a full step's spike is too large */           \
  S(f64, supply_voltage_v)                                                                              \
  S(f64, stall_force_n)         /* the motor's stall force at the tendon (N) */                         \
  S(f64, reflected_mass_kg)     /* rotor inertia reflected to the tendon (kg) */                        \
  S(f64, tendon_stiffness_n_per_m)                                                                      \
  S(f64, loadcell_gain_counts_per_n)                                                                    \
  S(f64, loadcell_min_counts)   /* the HX711's output range: its codes saturate there */                \
  S(f64, loadcell_max_counts)                                                                           \
  S(f64, loadcell_noise_n)      /* RMS (N) */                                                           \
  S(f64, loadcell_rate_hz)                                                                              \
  S(f64, tracker_noise_m)       /* RMS per axis (m) */                                                  \
  S(f64, tracker_noise_rad)     /* RMS per axis component (rad) */                                      \
  S(f64, tracker_rate_hz)                                                                               \
  S(f64, m_per_count)           /* tendon per encoder count (m) */                                      \
  S(f64, latency_s)             /* actuation latency (s) (effects; 0: none) */                          \
  S(f64, loadcell_lag_s)        /* load cells' first-order lag (s) (effects; 0: none) */                \
  S(f64, backlash_m)            /* play between spool and encoder (m) (effects; 0: none) */             \
  S(f64, damping_per_stiffness_s) /* a stiffened joint's damping per stiffness (s); 0: as built */     \
  S(f64, friction_coeff)        /* tendon friction μ per radian of wrap (effects; 0: none) */           \
  S(f64, presliding_m)          /* spool travel over which the friction turns round (m) */              \
  S(f64, friction_lag_s)        /* time constant of the tension the friction follows (s) */             \
  S(f64, friction_travel_lag_s) /* ... and of the spool travel that moves σ, on an ideal source (s) */ \
  S(f64, friction_motor_travel_lag_s) /* ... and while the motor drives the spool (s) */            \
  S(f64, friction_tension_cap_n) /* highest spool tension the friction follows (N) */                  \
  S(f64, friction_turn_beyond) /* share of a site's turn whose loss the next segment does not carry */ \
  S(f64, friction_jump_n)       /* a change of that pull in a step that needs short steps (N) */ \
  A(f64, slack_length_m, BL_MAX_CHANNELS)       /* slack edge of each tendon's spring now (m) */       \
  A(f64, taut_length_m, BL_MAX_CHANNELS)        /* ... in the straight pose (m) */                     \
  A(f64, loadcell_offset_counts, BL_MAX_CHANNELS)                                                       \
  A(f64, loadcell_gain, BL_MAX_CHANNELS)      /* a load cell senses gain · T + offset (effects) */     \
  A(f64, loadcell_offset_n, BL_MAX_CHANNELS)                                                            \
  A(f64, probe_position_m, BL_PROBE_VALUES)   /* probes A and B in the tip frame (m) */                \
  A(f64, probe_axis, BL_PROBE_VALUES)         /* their unit axes in the tip frame */                   \
  /* board inputs, refreshed before each bl_board_run */                                                \
  S(f64, power_up_s)            /* plant time of the firmware's power-up (s) */                         \
  S(f64, deadline_s)            /* board time at which the host's wait gives up (s) */                  \
  S(f64, last_write_s)          /* board time of the host's last write (s) */                           \
  S(f64, keepalive_s)           /* keepalive period (s); +inf for none */                               \
  /* carried across calls */                                                                            \
  S(f64, next_loadcell_s)       /* plant time of the next load-cell sample (s) */                       \
  S(f64, next_tracker_s)        /* plant time of the next tracker frame (s) */                          \
  S(f64, loadcell_time_s)       /* plant time of the latest load-cell sample (s) */                     \
  S(f64, tracker_time_s)        /* plant time of the latest tracker frame (s) */                        \
  A(f64, tracker_positions_m, BL_PROBE_VALUES)  /* the latest frame's probe positions, world (m) */    \
  A(f64, tracker_axes, BL_PROBE_VALUES)         /* and unit axes */                                    \
  A(f64, pwm_v, BL_MAX_CHANNELS)                /* voltages last given to the motors (V) */            \
  A(f64, peak_tension_n, BL_MAX_CHANNELS)       /* ground truth: the largest tension since cleared */  \
  A(f64, lagged_tension_n, BL_MAX_CHANNELS)     /* the load cells' low-passed tensions (N) */          \
  A(f64, encoder_position_m, BL_MAX_CHANNELS)   /* where each encoder is behind the play (m) */        \
  A(f64, sliding_state, BL_MAX_CHANNELS)        /* the friction's Dahl state σ per tendon (−1 … +1) */ \
  A(f64, friction_tension_n, BL_MAX_CHANNELS)   /* the lagged spool tension it follows (N) */          \
  A(f64, friction_spool_m, BL_MAX_CHANNELS)     /* the lagged spool position σ follows (m) */          \
  A(f64, friction_load_n, BL_MAX_CHANNELS)      /* the friction's pull at each path's end, last step (N) */ \
  A(f64, friction_wrap_rad, BL_MAX_CHANNELS)    /* each path's whole wrap at the last step (rad) */    \
  S(f64, jump_accel_m_s2)       /* spool acceleration step since the last physics step */               \
  S(f64, diverged_at_s)         /* plant time of the step MuJoCo reset after a warning (s); -1: none */  \
  S(i32, channels)              /* tendons of the plant */                                              \
  S(i32, noise_size)            /* draws in the buffer */                                               \
  S(i32, noise_cursor)          /* the next draw to take */                                             \
  S(i32, tip_site)                                                                                      \
  S(i32, stiffened_joints)      /* rows of geometry: joints the tendons' tension stiffens */           \
  S(i32, coupled_pairs)         /* ... then pairs of joints it couples */                              \
  S(i32, friction_sites_per_tendon)  /* sites of each path: spool, base hole, then towards the tip */   \
  S(i32, friction_primed)       /* 0 until friction_tension_n holds a tension */                        \
  S(i32, friction_joint_turns)  /* 1: fixed tendons: turns and pulls at the joints, 0: along the chords */ \
  S(i32, friction_jumped)       /* 1 after a step whose friction load changed by friction_jump_n */     \
  S(i32, base_substeps)         /* physics steps each step is cut into always (effects' stability) */  \
  S(i32, engage_substeps)       /* ... while a tendon could engage */                                   \
  S(i32, current_substeps)      /* what mjModel.opt.timestep is cut to now */                           \
  S(i32, tick_steps)            /* physics steps per board tick */                                      \
  S(i32, jump)                  /* 1 after a change the engagement check cannot bound */                \
  S(i32, short_steps)           /* steps taken as short ones since the plant was built */               \
  S(i32, mode)                  /* bl_mode; -1 before the first */                                      \
  S(i32, ctrl_pwm)              /* first actuator of each block: PWM motors, tension, length */         \
  S(i32, ctrl_tension)                                                                                  \
  S(i32, ctrl_length)                                                                                   \
  S(i32, group_pwm)             /* actuator group of each block */                                      \
  S(i32, group_tension)                                                                                 \
  S(i32, group_length)                                                                                  \
  A(i32, spool_qpos, BL_MAX_CHANNELS)                                                                   \
  A(i32, spool_dof, BL_MAX_CHANNELS)                                                                    \
  A(i32, raw_counts, BL_MAX_CHANNELS)           /* the latest load-cell sample (HX711 codes) */        \
  S(i32, loadcell_index)        /* index of the latest load-cell sample */                              \
  S(i32, tracker_index)         /* index of the latest tracker frame */                                 \
  S(i32, warnings_total)        /* sum of the MuJoCo warning counters seen */                           \
  S(i32, last_loadcell_index)   /* the board's: the sample the firmware has seen */                     \
  S(i32, held)                  /* 1 while the fixture holds the tensions (outputs ignored) */          \
  S(i32, have_applied)          /* 1 when applied_duty/applied_drive are what the plant has */          \
  S(i32, ticks)                 /* out: steps (bl_plant_run) or ticks (bl_board_run) in the call */     \
  S(i32, resume)                /* in: 1 to continue with the advance of a tick whose bytes went out */ \
  S(i32, delay_head)            /* the latency's ring: the slot of the next tick's outputs */           \
  S(i32, delay_filled)          /* ... and the ticks it holds */                                        \
  A(f32, applied_duty, BL_MAX_CHANNELS)                                                                 \
  A(f32, duty, BL_MAX_CHANNELS)                 /* the last tick's outputs */                          \
  A(f32, delay_duty, BL_DELAY_TICKS * BL_MAX_CHANNELS)  /* the last ticks' outputs, by ring slot */     \
  A(u8, applied_drive, BL_MAX_CHANNELS)                                                                 \
  A(u8, drive, BL_MAX_CHANNELS)                                                                         \
  A(u8, delay_drive, BL_DELAY_TICKS * BL_MAX_CHANNELS)

typedef void* bl_ptr;
typedef double* bl_f64p;
typedef double bl_f64;
typedef int32_t bl_i32;
typedef float bl_f32;
typedef uint8_t bl_u8;

struct bl_state {
#define BL_SCALAR(kind, name) bl_##kind name;
#define BL_ARRAY(kind, name, count) bl_##kind name[count];
  BL_STATE(BL_SCALAR, BL_ARRAY)
#undef BL_SCALAR
#undef BL_ARRAY
};

// One field of bl_state for the binding: its name, byte offset, kind and element count.
struct bl_field {
  const char* name;
  uint32_t offset;
  const char* kind;
  uint32_t count;
};

static const bl_field FIELDS[] = {
#define BL_SCALAR(kind, name) {#name, (uint32_t)offsetof(bl_state, name), #kind, 1},
#define BL_ARRAY(kind, name, count) {#name, (uint32_t)offsetof(bl_state, name), #kind, count},
    BL_STATE(BL_SCALAR, BL_ARRAY)
#undef BL_SCALAR
#undef BL_ARRAY
};

uint32_t bl_abi_version(void) { return BL_ABI_VERSION; }
uint32_t bl_state_size(void) { return (uint32_t)sizeof(bl_state); }
uint32_t bl_max_channels(void) { return BL_MAX_CHANNELS; }
const bl_field* bl_state_fields(uint32_t* count) {
  *count = (uint32_t)(sizeof(FIELDS) / sizeof(FIELDS[0]));
  return FIELDS;
}

// max(x, 0.0) that keeps x unless 0.0 is larger (so −0.0 and NaN pass through as they are).
static inline double max0(double x) { return 0.0 > x ? 0.0 : x; }

static int warnings_total(const mjData* d) {
  int total = 0;
  for (int i = 0; i < mjNWARNING; ++i) total += d->warning[i].number;
  return total;
}

// The tension of tendon i's dead-band spring (N): what the load cell at its spool carries.
static double spring_tension_n(const mjData* d, const bl_state* s, int i) {
  return max0(d->ten_length[i] - s->slack_length_m[i]) * s->tendon_stiffness_n_per_m;
}

// Draws one load-cell sample and one tracker frame may take.
static int noise_per_sample(const bl_state* s) { return s->channels + 2 * BL_PROBE_VALUES; }

// ---------------------------------------------------------------------------------------- drive

// Switch the spools' drive: enable the mode's actuator block, zero every control, give the
// spools the motors' rotor inertia in pwm and coast. A new length servo starts where the
// spools are, so switching modes does not jerk them.
static void set_mode(mjModel* m, mjData* d, bl_state* s, int mode) {
  if (s->mode == mode) return;
  s->mode = mode;
  int enabled = mode == BL_PWM ? s->group_pwm : mode == BL_TENSION ? s->group_tension
              : mode == BL_LENGTH ? s->group_length : -1;
  int groups[3] = {s->group_pwm, s->group_tension, s->group_length};
  int disabled = 0;
  for (int g : groups) {
    if (g != enabled) disabled |= 1 << g;
  }
  m->opt.disableactuator = disabled;
  for (int i = 0; i < m->nu; ++i) d->ctrl[i] = 0.0;
  s->jump = 1;
  for (int i = 0; i < s->channels; ++i) s->pwm_v[i] = 0.0;
  if (mode == BL_LENGTH) {
    for (int i = 0; i < s->channels; ++i) d->ctrl[s->ctrl_length + i] = d->qpos[s->spool_qpos[i]];
  }
  double armature = mode == BL_PWM || mode == BL_COAST ? s->reflected_mass_kg : 0.0;
  for (int i = 0; i < s->channels; ++i) m->dof_armature[s->spool_dof[i]] = armature;
}

// PWM duties (clipped to [−1, 1]) into the motors: H-bridge voltages, and the step in the spools'
// acceleration the engagement check has to allow for.
static void drive_pwm(mjModel* m, mjData* d, bl_state* s, const double* duty) {
  set_mode(m, d, s, BL_PWM);
  double volts[BL_MAX_CHANNELS];
  double largest = 0.0;
  for (int i = 0; i < s->channels; ++i) {
    volts[i] = fmin(fmax(duty[i], -1.0), 1.0) * s->supply_voltage_v;
    double change = fabs(volts[i] - s->pwm_v[i]);
    if (change > largest) largest = change;
  }
  double step_n = s->stall_force_n / s->supply_voltage_v * largest;
  s->jump_accel_m_s2 += step_n / s->reflected_mass_kg;
  for (int i = 0; i < s->channels; ++i) {
    s->pwm_v[i] = volts[i];
    d->ctrl[s->ctrl_pwm + i] = volts[i];
  }
}

// Plant.set_motor_pwm, coast, set_tensions and set_tendon_lengths: values are duties, unused,
// tensions (N) or relative lengths (m).
void bl_set_drive(mjModel* m, mjData* d, bl_state* s, int32_t mode, const double* values) {
  if (mode == BL_PWM) {
    drive_pwm(m, d, s, values);
    return;
  }
  set_mode(m, d, s, mode);
  if (mode == BL_COAST) return;
  int start = mode == BL_TENSION ? s->ctrl_tension : s->ctrl_length;
  for (int i = 0; i < s->channels; ++i) d->ctrl[start + i] = values[i];
  s->jump = 1;
}

// ---------------------------------------------------------------------------------------- sensors

// The motor encoders' quadrature counts: a counter changes at each edge, so the count is the
// floor of the tendon paid out over the tendon per edge.
// With backlash the encoder is where the play operator left it, not at the spool.
void bl_encoder_counts(const mjData* d, const bl_state* s, int32_t* counts) {
  for (int i = 0; i < s->channels; ++i) {
    double position_m = s->backlash_m > 0 ? s->encoder_position_m[i] : d->qpos[s->spool_qpos[i]];
    counts[i] = (int32_t)floor(position_m / s->m_per_count + 1e-9);
  }
}

// Load cells: HX711 codes of offset + gain · (loadcell_gain · T + loadcell_offset_n + noise),
// rounded to nearest (ties to even) and saturated at 24 bits; T is the tendon's spring tension.
static void sample_loadcells(const mjData* d, bl_state* s) {
  const double* z = s->loadcell_noise_n > 0 ? s->noise + s->noise_cursor : nullptr;
  if (z) s->noise_cursor += s->channels;
  for (int i = 0; i < s->channels; ++i) {
    double tension = s->loadcell_lag_s > 0 ? s->lagged_tension_n[i] : spring_tension_n(d, s, i);
    double sensed = s->loadcell_gain[i] * tension + s->loadcell_offset_n[i];
    if (z) sensed = sensed + s->loadcell_noise_n * z[i];
    double code = nearbyint(s->loadcell_offset_counts[i] + s->loadcell_gain_counts_per_n * sensed);
    s->raw_counts[i] = (int32_t)fmin(fmax(code, s->loadcell_min_counts), s->loadcell_max_counts);
  }
  s->loadcell_index += 1;
  s->loadcell_time_s = d->time;
  s->next_loadcell_s = (double)(s->loadcell_index + 1) / s->loadcell_rate_hz;
}

// The EM tracker's two 5-DOF probes on the tip: positions with Gaussian noise per axis, axes
// turned by a small random rotation each.
static void sample_tracker(const mjData* d, bl_state* s) {
  const double* p = d->site_xpos + 3 * s->tip_site;
  const double* r = d->site_xmat + 9 * s->tip_site;
  double noise_m[BL_PROBE_VALUES] = {0, 0, 0, 0, 0, 0}, noise_rad[BL_PROBE_VALUES];
  if (s->tracker_noise_m > 0) {
    for (int j = 0; j < BL_PROBE_VALUES; ++j) noise_m[j] = s->tracker_noise_m * s->noise[s->noise_cursor + j];
    s->noise_cursor += BL_PROBE_VALUES;
  }
  bool turn = s->tracker_noise_rad > 0;
  if (turn) {
    for (int j = 0; j < BL_PROBE_VALUES; ++j) noise_rad[j] = s->tracker_noise_rad * s->noise[s->noise_cursor + j];
    s->noise_cursor += BL_PROBE_VALUES;
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

// ---------------------------------------------------------------------------------------- stepping

// The continuous tendons to second order in the joint coordinates ξ (twin.sim.model.TendonLength):
// MuJoCo's fixed tendon is c·ξ, the tendon's length ℓ0 + c·ξ + ½ ξᵀHξ. With each tendon's tension
// T from the last step: a stiffened joint's stiffness is its own plus Σ T_i H_i,jj, which the
// discrete integrator takes implicitly like the joint's own (its damping too, damping_per_stiffness_s
// times it); a coupled pair of joints pulls on each
// other with −Σ T_i H_i,ab ξ, explicitly (small beside the joints' own stiffness, which damps it);
// and each tendon's slack edge moves in by ½ ξᵀH_iξ, so that its spring stretches with its length.
static void tendon_geometry(mjModel* m, mjData* d, bl_state* s) {
  int n = s->channels;
  double tension[BL_MAX_CHANNELS], lengthening[BL_MAX_CHANNELS];
  for (int i = 0; i < n; ++i) {
    tension[i] = spring_tension_n(d, s, i);
    lengthening[i] = 0.0;
  }
  const double* row = s->geometry;
  const int32_t* index = (const int32_t*)s->geometry_index;
  for (int j = 0; j < s->stiffened_joints; ++j, row += 1 + n, index += 2) {
    double q = d->qpos[index[1]];
    double stiffness = row[0];
    for (int i = 0; i < n; ++i) {
      stiffness += tension[i] * row[1 + i];
      lengthening[i] += 0.5 * row[1 + i] * q * q;
    }
    m->jnt_stiffness[index[0]] = stiffness;
    // Stiffness-proportional damping of the stiffness the joint has now: undamped, the tension's
    // share leaves a soft shear slide ringing (the thesis's G = 4.76e4 Pa: 224 N/m of its own
    // under some 1000 N/m of tension, damping ratio a fifth of the others').
    if (s->damping_per_stiffness_s > 0) m->dof_damping[m->jnt_dofadr[index[0]]] = s->damping_per_stiffness_s * stiffness;
  }
  for (int p = 0; p < s->coupled_pairs; ++p) {
    d->qfrc_applied[index[4 * p + 1]] = 0.0;
    d->qfrc_applied[index[4 * p + 3]] = 0.0;
  }
  for (int p = 0; p < s->coupled_pairs; ++p, row += n, index += 4) {
    double qa = d->qpos[index[0]], qb = d->qpos[index[2]];
    double stiffness = 0.0;
    for (int i = 0; i < n; ++i) {
      stiffness += tension[i] * row[i];
      lengthening[i] += row[i] * qa * qb;
    }
    d->qfrc_applied[index[1]] -= stiffness * qb;
    d->qfrc_applied[index[3]] -= stiffness * qa;
  }
  for (int i = 0; i < n; ++i) {
    s->slack_length_m[i] = s->taut_length_m[i] - lengthening[i];
    m->tendon_lengthspring[2 * i + 1] = s->slack_length_m[i];
  }
}

// Could a tendon that is slack or nearly so engage within the next ``chunk`` steps with a full
// step's spike over the limit? The closing speed is bounded from the last step: the tendon's
// speed, plus its acceleration (ten_J · qacc, the last step's velocity change per second) and
// the spools' acceleration step from a new PWM drive, over the span and the one step the
// kinematics lag behind. After a change it cannot bound (jump), any tendon near slack counts.
static bool engage_risk(const mjModel* m, const mjData* d, const bl_state* s, int chunk) {
  double span = chunk * s->step_s + s->step_s;
  for (int i = 0; i < s->channels; ++i) {
    double stretch = d->ten_length[i] - s->slack_length_m[i];
    if (!(stretch < s->engage_stretch_m)) continue;
    if (s->jump) return true;
    double acc = 0.0;
    int start = m->ten_J_rowadr[i], end = start + m->ten_J_rownnz[i];
    for (int k = start; k < end; ++k) acc += d->ten_J[k] * d->qacc[m->ten_J_colind[k]];
    double a = max0(acc) + s->jump_accel_m_s2;
    double v = max0(d->ten_velocity[i]);
    if (v + a * span > s->engage_speed_m_s && stretch + (v + 0.5 * a * span) * span > 0.0) return true;
  }
  return false;
}

// The effects' per-step state after a physics step: the load cells' low-pass (exact for a
// tension held over the step) and the encoders' play operator (an encoder moves only once the
// spool has taken up half the play on one side of it).
static void dynamics_after_step(const mjModel* m, const mjData* d, bl_state* s) {
  if (s->loadcell_lag_s > 0) {
    double blend = 1.0 - exp(-m->opt.timestep / s->loadcell_lag_s);
    for (int i = 0; i < s->channels; ++i) {
      s->lagged_tension_n[i] += blend * (spring_tension_n(d, s, i) - s->lagged_tension_n[i]);
    }
  }
  if (s->backlash_m > 0) {
    double half = 0.5 * s->backlash_m;
    for (int i = 0; i < s->channels; ++i) {
      double q = d->qpos[s->spool_qpos[i]];
      if (q - s->encoder_position_m[i] > half) s->encoder_position_m[i] = q - half;
      if (q - s->encoder_position_m[i] < -half) s->encoder_position_m[i] = q + half;
    }
  }
}

// The effects' state at t = 0: filters at the tensions, encoders at the spools.
static void dynamics_reset(const mjData* d, bl_state* s) {
  for (int i = 0; i < s->channels; ++i) {
    s->lagged_tension_n[i] = spring_tension_n(d, s, i);
    s->encoder_position_m[i] = d->qpos[s->spool_qpos[i]];
  }
  s->delay_head = 0;
  s->delay_filled = 0;
  for (int i = 0; i < s->channels; ++i) s->sliding_state[i] = 0.0, s->friction_wrap_rad[i] = 0.0, s->friction_load_n[i] = 0.0;
  s->friction_primed = 0;
  s->friction_jumped = 0;
}

// Capstan friction of the tendons at the disc holes (twin.effects.tendon_friction.TendonFriction,
// which documents the model): MuJoCo's tendon carries the spool's tension T0 along its whole
// path; with friction the tension in segment k is T0 exp(−σ μ θ_k), θ_k the wrap from the spool to
// site k, σ each tendon's Dahl sliding state. The difference is applied at the path's sites as
// forces along the chords (and their moments about each body's centre of mass) through
// xfrc_applied, or, for fixed tendons, on the joints in each site's plane through qfrc_applied
// as the fixed tendon pulls them. Computed
// here, before every physics step, so that a twin with friction steps at the speed of one without
// and a Ctrl-C reaches Python between the loop's calls.
// The angle between two unit chords (rad): the turn of a line that runs straight between sites.
static double chord_turn(const double* before, const double* after) {
  double c = before[0] * after[0] + before[1] * after[1] + before[2] * after[2];
  return acos(c > 1.0 ? 1.0 : c < -1.0 ? -1.0 : c);
}

// The turn (rad) of a continuously routed tendon across the joint between bodies a and b, whose
// chords before and after it are unit vectors: |φ × t| with φ the rotation vector of b relative
// to a and t the tendon's direction there, the joint's share of the predictor's wrap ∫|u × t| ds
// (twin.rod.kernel). The angle between the chords is not: a twist hinge moves the next site
// sideways by r·φz, which tilts the chord by r·φz/h without bending the tendon (a 100 mm rod with
// G·J torsion under a 10 g tip counted 4 % more wrap so than the predictor).
static double joint_turn(const mjData* d, int a, int b, const double* before, const double* after) {
  if (a == b) return 0.0;
  const double* ra = d->xmat + 9 * a;
  const double* rb = d->xmat + 9 * b;
  double r[3][3];  // rb · raᵀ: b's orientation relative to a's, in the world frame
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r[i][j] = rb[3 * i] * ra[3 * j] + rb[3 * i + 1] * ra[3 * j + 1] + rb[3 * i + 2] * ra[3 * j + 2];
  double w[3] = {0.5 * (r[2][1] - r[1][2]), 0.5 * (r[0][2] - r[2][0]), 0.5 * (r[1][0] - r[0][1])};
  double sine = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
  double angle = atan2(sine, 0.5 * (r[0][0] + r[1][1] + r[2][2] - 1.0));
  double scale = sine > 1e-300 ? angle / sine : 1.0;
  double t[3] = {before[0] + after[0], before[1] + after[1], before[2] + after[2]};
  double norm = sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
  if (norm <= 0.0) return 0.0;
  double c[3] = {w[1] * t[2] - w[2] * t[1], w[2] * t[0] - w[0] * t[2], w[0] * t[1] - w[1] * t[0]};
  return scale * sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]) / norm;
}

// Before the tendons' second order (which sets its coupled joints' qfrc_applied afresh): the
// joints the friction pulls (fixed tendons), cleared for tendon_friction to add to.
static void tendon_friction_clear(mjData* d, const bl_state* s) {
  if (!s->friction_joint_turns) return;
  const int32_t* dofs = (const int32_t*)s->friction_joint_dofs;
  for (int k = 0; k < 6 * s->channels * s->friction_sites_per_tendon; ++k)
    if (dofs[k] >= 0) d->qfrc_applied[dofs[k]] = 0.0;
}

// How far (m) each spool on an ideal tension source moves while the friction of every tendon
// turns over by a unit of σ and the rod follows at rest: the tendons' length compliance through
// the rod's joint springs, c_ij = Σ J_i J_j / k over the dofs (MuJoCo's tendon Jacobian, sorted
// sparse rows; the spools' and other unsprung dofs left out), each tendon's average friction
// swing per unit σ ``swing_n`` taken up through it, summed in magnitude over the tendons whose
// friction moves this spool. Summed so, no combination of turns can move a spool by more.
static void rod_travel_m(const mjModel* m, const mjData* d, const bl_state* s, const double* swing_n, double* out) {
  int n = s->channels;
  for (int i = 0; i < n; ++i) {
    out[i] = 0.0;
    int ai = m->ten_J_rowadr[i], ei = ai + m->ten_J_rownnz[i];
    for (int j = 0; j < n; ++j) {
      if (!(swing_n[j] > 0.0)) continue;
      int a = ai, b = m->ten_J_rowadr[j], eb = b + m->ten_J_rownnz[j];
      double c = 0.0;
      while (a < ei && b < eb) {
        int ca = m->ten_J_colind[a], cb = m->ten_J_colind[b];
        if (ca < cb) { ++a; continue; }
        if (cb < ca) { ++b; continue; }
        double k = m->jnt_stiffness[m->dof_jntid[ca]];
        if (k > 0.0) c += d->ten_J[a] * d->ten_J[b] / k;
        ++a, ++b;
      }
      out[i] += fabs(c) * swing_n[j];
    }
  }
}

static void tendon_friction(const mjModel* m, mjData* d, bl_state* s) {
  int n = s->channels, sites = s->friction_sites_per_tendon;
  const int32_t* path = (const int32_t*)s->friction_sites;
  double dt = m->opt.timestep;
  double moved_m[BL_MAX_CHANNELS], swing_n[BL_MAX_CHANNELS];
  for (int i = 0; i < n; ++i) {
    double tension = spring_tension_n(d, s, i), spool_m = d->qpos[s->spool_qpos[i]];
    moved_m[i] = 0.0, swing_n[i] = 0.0;
    if (!s->friction_primed) {
      s->friction_tension_n[i] = tension < s->friction_tension_cap_n ? tension : s->friction_tension_cap_n;
      s->friction_spool_m[i] = spool_m;
      continue;
    }
    // A tendon snapping taut spikes for a step far beyond anything the rig holds: not followed
    // (twin.effects.tendon_friction.FRICTION_TENSION_CAP_LIMITS says why).
    // An ideal tension source (the fixture's dead weights, twin sim, the cross-check) holds the
    // spool's tension at its setting: the spikes its light carriage rings with against the stiff
    // line are the carriage's, not the source's, and are not followed either. Followed, they came
    // back as friction of up to e^(μθ) − 1 times them: the long robot pulled by 20 N at μ = 0.6,
    // curled past a full turn, threw 380 N at a slack antagonist and diverged within 0.2 s.
    double cap = s->friction_tension_cap_n;
    if (s->mode == BL_TENSION && d->ctrl[s->ctrl_tension + i] < cap) cap = max0(d->ctrl[s->ctrl_tension + i]);
    double followed = tension < cap ? tension : cap;
    s->friction_tension_n[i] += (followed - s->friction_tension_n[i]) * (dt / (s->friction_lag_s + dt));
    // The spool pulls tendon in while its position (tendon paid out) falls.
    // A spool the motor drives carries the rotor; on an ideal source it is a light carriage.
    double lag_s = s->mode == BL_PWM || s->mode == BL_COAST ? s->friction_motor_travel_lag_s : s->friction_travel_lag_s;
    moved_m[i] = (spool_m - s->friction_spool_m[i]) * (dt / (lag_s + dt));
    s->friction_spool_m[i] += moved_m[i];
    // Turning the friction round changes the tension along the path by up to 2 T0 sinh(μ θ) at
    // its end, about half that on average: per unit of σ, T0 sinh(μ θ) / 2.
    swing_n[i] = 0.5 * s->friction_tension_n[i] * sinh(s->friction_coeff * s->friction_wrap_rad[i]);
  }
  double rod_m[BL_MAX_CHANNELS];
  // Not under the fixture's dead weights (held), which pull the board's bent rod back to nearly
  // straight between a sweep's rows and hand it to the holder: left as they were, every
  // board-driven run stays as it was (with them, the endoscope's quick sweep at μ 0.3 moved by
  // up to 0.1 mm in its last rows).
  bool rod = s->friction_primed && s->mode == BL_TENSION && !s->held;
  if (rod) rod_travel_m(m, d, s, swing_n, rod_m);
  // The share of the rod's travel σ turns over at least: each step the turn's own travel comes back
  // through the lag's blend b = dt / (τ + dt), and for a rod that followed σ within the step the
  // update's error would fall by 1 − b (1 + G / L) a step: without ringing for G / L ≤ τ / dt.
  // The rod takes longer than a step and the sum over tendons bounds its travel from above. At
  // 0.1 and 0.15 of the travel the two-segment robot's bent rows with 10 g still moved after
  // 3 s; at the whole travel the long robot's swing did, its friction too soft to take any of
  // it (μ 0.3 and 0.6, κ 13 and 26.2 1/m).
  double share = s->friction_travel_lag_s > dt ? dt / s->friction_travel_lag_s : 1.0;
  for (int i = 0; i < n && s->friction_primed; ++i) {
    // The tendon takes the swing up over its stretch before it slides: σ turns over at least
    // that travel. Over a fixed few hundredths of a millimetre a large friction (27 N on a bent
    // stiff robot at μ = 0.6: a 30 N swing) turned within one step, and the explicit swing it
    // threw at the rod, back and forth, never let it rest or diverged; below 16 N of swing
    // nothing changes.
    double stretch_m = swing_n[i] / s->tendon_stiffness_n_per_m;
    // On an ideal tension source nothing holds the spool: the swing moves it by the rod's
    // compliance as well, 5 mm per unit of σ in a bent row of the long robot at μ = 0.6
    // (κ 13 1/m, 10 g) against its 4 µm of stretch. σ turning over a shorter travel than that
    // is turned back by its own swing and overshoots, every step (the twin chattered at 67 Hz
    // and never came to rest); over a share of it, each turn moves the spool by a bounded
    // multiple of the travel it turned over, and the lag rings that down.
    if (rod) stretch_m += share * rod_m[i];
    double step = -moved_m[i] / (stretch_m > s->presliding_m ? stretch_m : s->presliding_m);
    if (step != 0.0) {
      double value = s->sliding_state[i] + step;
      s->sliding_state[i] = value > 1.0 ? 1.0 : value < -1.0 ? -1.0 : value;
    }
  }
  s->friction_primed = 1;
  if (!s->friction_joint_turns) {
    for (int k = 0; k < n * sites; ++k) {
      double* f = d->xfrc_applied + 6 * m->site_bodyid[path[k]];
      for (int j = 0; j < 6; ++j) f[j] = 0.0;
    }
  }
  const int32_t* joint_dofs = (const int32_t*)s->friction_joint_dofs;
  for (int i = 0; i < n; ++i) {
    const int32_t* row = path + i * sites;
    double t0 = s->friction_tension_n[i], decay = -s->sliding_state[i] * s->friction_coeff;
    double wrap = 0.0, before[3] = {0.0, 0.0, 0.0}, load_n = 0.0;
    for (int k = 0; k + 1 < sites; ++k) {
      const double* a = d->site_xpos + 3 * row[k];
      const double* b = d->site_xpos + 3 * row[k + 1];
      double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
      double norm = sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
      if (norm <= 0.0) break;  // past the tendon's anchor: its path repeats the anchor site
      u[0] /= norm, u[1] /= norm, u[2] /= norm;
      if (k > 0) {
        double turn = s->friction_joint_turns ? joint_turn(d, m->site_bodyid[row[k]], m->site_bodyid[row[k + 1]], before, u)
                                              : chord_turn(before, u);
        wrap += turn;
        // Segment k pulls site k towards site k + 1 and site k + 1 back, with T_k − T0. Where a
        // site stands for a bend spread over the bodies on both sides of it (a joint's plane),
        // segment k carries the loss of half its turn, the next segment the rest.
        double excess = t0 * (exp(decay * (wrap - s->friction_turn_beyond * turn)) - 1.0);
        load_n = fabs(excess);
        if (s->friction_joint_turns) {
          // The joints in site k's plane, pulled as the fixed tendon pulls them (−T ∂ℓ/∂ξ) with
          // T_k − T0: the tension there is T_k.
          int at = 6 * (i * sites + k);
          for (int j = 0; j < 6 && joint_dofs[at + j] >= 0; ++j)
            d->qfrc_applied[joint_dofs[at + j]] -= excess * s->friction_joint_coefficients[at + j];
          before[0] = u[0], before[1] = u[1], before[2] = u[2];
          continue;
        }
        for (int end = 0; end < 2; ++end) {
          int site = row[k + end];
          double sign = end ? -excess : excess;
          double force[3] = {sign * u[0], sign * u[1], sign * u[2]};
          int body = m->site_bodyid[site];
          const double* at = d->site_xpos + 3 * site;
          const double* com = d->xipos + 3 * body;
          double r[3] = {at[0] - com[0], at[1] - com[1], at[2] - com[2]};
          double* out = d->xfrc_applied + 6 * body;
          out[0] += force[0], out[1] += force[1], out[2] += force[2];
          out[3] += r[1] * force[2] - r[2] * force[1];
          out[4] += r[2] * force[0] - r[0] * force[2];
          out[5] += r[0] * force[1] - r[1] * force[0];
        }
      }
      before[0] = u[0], before[1] = u[1], before[2] = u[2];
    }
    s->friction_wrap_rad[i] = wrap;
    if (fabs(load_n - s->friction_load_n[i]) > s->friction_jump_n) s->friction_jumped = 1;
    s->friction_load_n[i] = load_n;
  }
}

// ``chunk`` physics steps, cut into shorter ones where a tendon could engage, then the samples
// that have come due. Returns 0, or BL_WARNING.
static int plant_chunk(mjModel* m, mjData* d, bl_state* s, int chunk) {
  bl_mj_fn step = (bl_mj_fn)s->step_fn;
  bl_hook_fn hook = (bl_hook_fn)s->hook_fn;
  int substeps = s->base_substeps;
  // A friction load that jumped (the friction turning round on a spool let go at a high
  // tension, a rod whipping) is a change an explicit 5 ms step cannot follow either.
  if (s->engage_substeps > substeps && (s->friction_jumped || engage_risk(m, d, s, chunk))) {
    substeps = s->engage_substeps;
    s->short_steps += chunk;
  }
  s->jump = 0;
  s->friction_jumped = 0;
  s->jump_accel_m_s2 = 0.0;
  if (substeps != s->current_substeps) {
    m->opt.timestep = s->step_s / substeps;
    s->current_substeps = substeps;
  }
  bool geometry = s->stiffened_joints || s->coupled_pairs;
  bool dynamics = s->loadcell_lag_s > 0 || s->backlash_m > 0;
  // Attached friction runs at any μ: one set to 0 at run time (twin.sim.events) then clears the
  // forces it applied last instead of leaving them on.
  bool friction = s->friction_sites != 0;
  for (int k = 0; k < chunk * substeps; ++k) {
    if (friction) tendon_friction_clear(d, s);
    if (geometry) tendon_geometry(m, d, s);
    if (friction) tendon_friction(m, d, s);
    if (hook) hook();
    double before_s = d->time;
    step(m, d);
    // A diverged step resets the data (time 0): keep when it was, for the error.
    if (d->time < before_s && s->diverged_at_s < 0) s->diverged_at_s = before_s;
    if (dynamics) dynamics_after_step(m, d, s);
    for (int i = 0; i < s->channels; ++i) {
      double tension = spring_tension_n(d, s, i);
      if (tension > s->peak_tension_n[i]) s->peak_tension_n[i] = tension;
    }
  }
  int total = warnings_total(d);
  if (total != s->warnings_total) {
    s->warnings_total = total;
    return BL_WARNING;
  }
  if (d->time >= s->next_loadcell_s - 1e-9) sample_loadcells(d, s);
  if (d->time >= s->next_tracker_s - 1e-9) sample_tracker(d, s);
  return 0;
}

// Physics steps up to the next sensor sample, at least one.
static int steps_to_next_sample(const mjData* d, const bl_state* s) {
  double next_s = s->next_tracker_s < s->next_loadcell_s ? s->next_tracker_s : s->next_loadcell_s;
  int until = (int)ceil((next_s - d->time) / s->step_s - 1e-9);
  return until < 1 ? 1 : until;
}

// Plant.step: ``steps`` physics steps in chunks that end at the sensor samples. s->ticks counts
// the steps taken, also when it returns early for a noise refill or a warning.
int bl_plant_run(mjModel* m, mjData* d, bl_state* s, int32_t steps) {
  s->ticks = 0;
  while (s->ticks < steps) {
    if (s->noise_size - s->noise_cursor < noise_per_sample(s)) return BL_NOISE;
    int chunk = steps - s->ticks;
    int until = steps_to_next_sample(d, s);
    if (until < chunk) chunk = until;
    s->ticks += chunk;
    int reason = plant_chunk(m, d, s, chunk);
    if (reason) return reason;
  }
  return BL_DONE;
}

// Plant.reset after mj_resetData: braked motors (pwm, duty 0), the model brought up to date,
// the first samples taken at t = 0.
int bl_plant_reset(mjModel* m, mjData* d, bl_state* s) {
  s->mode = -1;
  set_mode(m, d, s, BL_PWM);
  s->jump_accel_m_s2 = 0.0;
  // Straight and slack after mj_resetData: each tendon's own slack edge, the joints' own stiffness.
  if (s->stiffened_joints || s->coupled_pairs) tendon_geometry(m, d, s);
  ((bl_mj_fn)s->forward_fn)(m, d);
  dynamics_reset(d, s);
  if (s->noise_size - s->noise_cursor < noise_per_sample(s)) return BL_NOISE;
  s->loadcell_index = -1;
  s->tracker_index = -1;
  sample_loadcells(d, s);
  sample_tracker(d, s);
  s->warnings_total = warnings_total(d);
  return BL_DONE;
}

// ---------------------------------------------------------------------------------------- board

static bool same_outputs(const bl_state* s, const float* duty, const uint8_t* drive) {
  if (!s->have_applied) return false;
  for (int i = 0; i < s->channels; ++i) {
    uint32_t a, b;
    __builtin_memcpy(&a, &duty[i], 4);
    __builtin_memcpy(&b, &s->applied_duty[i], 4);
    if (a != b || drive[i] != s->applied_drive[i]) return false;
  }
  return true;
}

// The actuation latency: keep this tick's outputs in the ring and give the ones of
// latency_s ago, the duty interpolated between the two ticks around it and the drive of the
// nearer one. Until the ring holds that many ticks, the oldest it holds stands in.
static void delayed_outputs(bl_state* s, float* duty, uint8_t* drive) {
  int n = s->channels;
  int slot = s->delay_head;
  for (int i = 0; i < n; ++i) {
    s->delay_duty[slot * BL_MAX_CHANNELS + i] = s->duty[i];
    s->delay_drive[slot * BL_MAX_CHANNELS + i] = s->drive[i];
  }
  s->delay_head = (slot + 1) % BL_DELAY_TICKS;
  if (s->delay_filled < BL_DELAY_TICKS) s->delay_filled += 1;
  double ticks = s->latency_s / (s->tick_steps * s->step_s);
  int back = (int)floor(ticks);
  double frac = ticks - back;
  int oldest = s->delay_filled - 1;
  int a = back < oldest ? back : oldest, b = back + 1 < oldest ? back + 1 : oldest;
  const float* newer = s->delay_duty + ((slot - a + BL_DELAY_TICKS) % BL_DELAY_TICKS) * BL_MAX_CHANNELS;
  const float* older = s->delay_duty + ((slot - b + BL_DELAY_TICKS) % BL_DELAY_TICKS) * BL_MAX_CHANNELS;
  const uint8_t* nearer = s->delay_drive + ((slot - (frac < 0.5 ? a : b) + BL_DELAY_TICKS) % BL_DELAY_TICKS) * BL_MAX_CHANNELS;
  for (int i = 0; i < n; ++i) {
    duty[i] = (float)((1.0 - frac) * newer[i] + frac * older[i]);
    drive[i] = nearer[i];
  }
}

// The firmware's outputs into the plant. The control loop runs at 100 Hz and the board ticks at
// 200 Hz, so every other tick repeats the outputs: the plant already has them. Duty 0 brakes
// (H-bridge outputs shorted); all motors coasting opens the bridges. While the fixture holds the
// tensions the outputs are ignored.
static void apply_outputs(mjModel* m, mjData* d, bl_state* s) {
  const float* out_duty = s->duty;
  const uint8_t* out_drive = s->drive;
  float late_duty[BL_MAX_CHANNELS];
  uint8_t late_drive[BL_MAX_CHANNELS];
  if (s->latency_s > 0) {
    delayed_outputs(s, late_duty, late_drive);
    out_duty = late_duty;
    out_drive = late_drive;
  }
  if (s->held) {
    s->have_applied = 0;
    return;
  }
  if (same_outputs(s, out_duty, out_drive)) return;
  bool coast = true;
  double duty[BL_MAX_CHANNELS];
  for (int i = 0; i < s->channels; ++i) {
    coast = coast && out_drive[i] == BL_DRIVE_COAST;
    duty[i] = out_drive[i] == BL_DRIVE_ON ? (double)out_duty[i] : 0.0;
  }
  if (coast) {
    set_mode(m, d, s, BL_COAST);
  } else {
    drive_pwm(m, d, s, duty);
  }
  for (int i = 0; i < s->channels; ++i) {
    s->applied_duty[i] = out_duty[i];
    s->applied_drive[i] = out_drive[i];
  }
  s->have_applied = 1;
}

// The emulated board, tick by tick (5 ms, the Teensy's IntervalTimer): the firmware runs at the
// board time with the encoders and, on a new sample, the load cells; its outputs go to the
// motors; then the plant advances by a tick. Returns before a tick when the host has work
// (deadline, keepalive, noise) and after the firmware when it has queued bytes (BL_TX: the next
// call with resume = 1 advances that tick and returns BL_DONE).
int bl_board_run(mjModel* m, mjData* d, bl_state* s, int32_t max_ticks) {
  s->ticks = 0;
  bool resume = s->resume != 0;
  s->resume = 0;
  while (resume || s->ticks < max_ticks) {
    if (!resume) {
      double board_s = d->time - s->power_up_s;
      if (board_s >= s->deadline_s) return BL_DEADLINE;
      if (isfinite(s->keepalive_s) && board_s - s->last_write_s >= s->keepalive_s - 1e-9) return BL_KEEPALIVE;
      // A tick's advance samples at most once per chunk, and it has at most tick_steps chunks.
      if (s->noise_size - s->noise_cursor < s->tick_steps * noise_per_sample(s)) return BL_NOISE;
      int32_t counts[BL_MAX_CHANNELS];
      bl_encoder_counts(d, s, counts);
      uint32_t mask = s->loadcell_index != s->last_loadcell_index ? (1u << s->channels) - 1u : 0u;
      s->last_loadcell_index = s->loadcell_index;
      ((bl_tick_fn)s->tick_fn)(s->firmware, (uint64_t)nearbyint(board_s * 1e6), counts, s->raw_counts, mask,
                               s->duty, s->drive);
      s->ticks += 1;
      apply_outputs(m, d, s);
      if (((bl_pending_fn)s->pending_fn)(s->firmware) > 0) return BL_TX;
    }
    // The tick's advance: Plant.step(TICK_S).
    for (int taken = 0; taken < s->tick_steps;) {
      int chunk = s->tick_steps - taken;
      int until = steps_to_next_sample(d, s);
      if (until < chunk) chunk = until;
      taken += chunk;
      int reason = plant_chunk(m, d, s, chunk);
      if (reason) return reason;
    }
    // After a delivery the host's wait looks at what arrived before the next tick.
    if (resume) return BL_DONE;
  }
  return BL_DONE;
}

}  // extern "C"
