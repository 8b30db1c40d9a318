/* The pneumatic muscle as a MuJoCo actuator plugin: "wpam_mj.muscle".

   The physics is not here: it is wpam_mj/physics/kernel.py, written once, which
   wpam_mj/physics/kernel_codegen.py writes into the generated header as C (kernel_*:
   geometry, force, friction, the Pi feedforward, ISO 6358 flow, the chambers' Euler step,
   the regulators' lag, the Po feedback) and which the Python engine
   (wpam_mj/simulation/engine.py) calls as it is, so the two are bit-identical
   (tests/test_plugin.py). This file holds the step and the callbacks, the state glue
   around those calls; muscle_config.c reads, checks and derives the configuration (every
   range it must lie in is the rule table of wpam_mj/physics/rules.py, generated into
   WPAM_RULES), muscle_handles.c keeps the Instances, and muscle_plugin.h holds what they
   share.

   Built with -ffp-contract=off and without -ffast-math (no fused multiply-adds, no
   reassociation); libm's sqrt, pow, sin, cos, asin, expm1 are the functions Python's floats
   call. min/max follow Python's builtins (py_min, py_max of the generated header).

   One plugin instance is one muscle on one tendon. The actuators that name the instance
   are its input channels in model order (WPAM_CONTROLS; docs/plugin.md): all act on the
   muscle's tendon, the first carries the force. The callbacks, as MuJoCo calls them:
     nstate   (compile) the state size: the named fields and the regulators' dead-time
              queues, fixed for the time step the model compiles with;
     init     (compile and every new mjData) the configuration read, checked against the
              rules and derived once into this mjData's Instance; a bad one fails the
              compile with one line (mju_error: never on the step path);
     compute  (mj_fwdActuation, after the constraint rows are made, before the solve) the
              contraction and its velocity from the tendon, the commands, the Po
              controller's output (nothing committed: compute may run more than once per
              step), the tendon force from the chamber pressures, the friction level into
              this simulation's friction row of the tendon (set_friction_level);
     advance  (after integration, once per step) the controller's state committed, the
              regulators and chambers advanced from the values compute used.
   Everything that changes lives in plugin_state (layout WPAM_STATE). The Instance of an
   mjData holds only what its model and configuration determine, plus where the friction
   row was last step; it is found through a handle that a copied or unpickled mjData
   cannot mistake for its own (instance_of).

   Pressures: *_gauge above the atmosphere, *_abs absolute; SI throughout (m, m/s, Pa, N,
   kg/s, s). */

#include <math.h>
#include <stdint.h>

#include "muscle_plugin.h" /* the types, tables and functions the plugin's files share */

/* Every configuration attribute: the instance's keys, then every parameter by name. */
static const char* const ATTRIBUTES[] = {WPAM_INSTANCE_KEYS WPAM_PARAMS(AS_NAME)};
#define NATTRIBUTE ((int)(sizeof(ATTRIBUTES) / sizeof(ATTRIBUTES[0])))

/* ---- the kernel's pneumatics and control (wpam_mj/physics/kernel.py) at an Instance's
   constants ---- */

/* The Pi [Pa gauge] that holds x_ref under the feedforward load at Po = po_feedforward on
   the branch feedforward_friction, clipped to the regulator range (control.pi_feedforward). */
static double pi_feedforward(const Instance* k, double x_ref) {
  const double* p = k->p;
  double pi_gauge = kernel_equilibrium_pressure(
      p[P_CONTROLLER_PO_FEEDFORWARD], k->feedforward_load, p[P_CONTROLLER_FEEDFORWARD_FRICTION],
      area_at(k, x_ref), rubber_at(k, x_ref), p[P_MUSCLE_OUTPUT_COEFF],
      p[P_MUSCLE_FRICTION_COEFF], p[P_MUSCLE_FRICTION_CONST], p[P_MUSCLE_AXIAL_AREA]);
  return kernel_clip(pi_gauge, p[P_PNEUMATICS_P_MIN], p[P_PNEUMATICS_P_MAX]);
}

/* A regulator's flow into its chamber at set point `set_gauge` [Pa gauge] through the line of
   conductance `line` (kernel.regulator_flow) [kg/s]. */
static double regulator_flow(const Instance* k, double set_gauge, double chamber_abs,
                             double line) {
  double atmosphere = k->p[P_PNEUMATICS_ATMOSPHERE];
  return kernel_regulator_flow(set_gauge + atmosphere, chamber_abs,
                               k->p[P_PNEUMATICS_SUPPLY_PRESSURE] + atmosphere, atmosphere,
                               line, k->p[P_PNEUMATICS_SUPPLY_VALVE_CONDUCTANCE],
                               k->p[P_PNEUMATICS_EXHAUST_VALVE_CONDUCTANCE],
                               k->p[P_PNEUMATICS_CRITICAL_RATIO]);
}

/* A regulator's step (Regulator.update): the command through the dead time (ring buffer
   `queue`, shared head), then kernel.regulator_set_point. Returns the set point [Pa gauge]. */
static double regulator_update(const Instance* k, double* set_gauge, double* queue,
                               int head, double command) {
  if (k->delay_steps) {
    double held = queue[head];
    queue[head] = command;
    command = held;
  }
  *set_gauge = kernel_regulator_set_point(*set_gauge, command, k->p[P_PNEUMATICS_P_MAX],
                                          k->lag_alpha);
  return *set_gauge;
}

/* Regulator.rest: every command in flight and the set point at a held command. */
static void regulator_rest(const Instance* k, double* set_gauge, double* queue,
                           double command) {
  int i;
  for (i = 0; i < k->delay_steps; i++) queue[i] = command;
  *set_gauge = kernel_regulator_clamp(command, k->p[P_PNEUMATICS_P_MAX]);
}

/* kernel.po_feedback on the committed state s: the Po command, and what advance commits. */
static double feedback_output(const Instance* k, const double* s, double x, double x_ref,
                              double po_ff, double* integral_next, double* derivative,
                              double* e_out) {
  const double* p = k->p;
  double u;
  kernel_po_feedback(x, x_ref, po_ff, s[S_INTEGRAL], s[S_DERIVATIVE], s[S_E_PREV],
                     s[S_HAS_PREV] != 0.0, p[P_CONTROLLER_KP], p[P_CONTROLLER_KI], k->kd,
                     p[P_CONTROLLER_DERIVATIVE_FILTER], k->pa_per_unit, p[P_PNEUMATICS_P_MIN],
                     p[P_CONTROLLER_PO_CAP], k->dt, &u, integral_next, derivative, e_out);
  return u;
}

/* ---- the state of one instance ---- */

static double* queue_i(double* s) { return s + S_COUNT; }
static double* queue_o(const Instance* k, double* s) { return s + S_COUNT + k->delay_steps; }

/* Initial state: vented chambers, empty regulators, controller at its bumpless start. */
static void state_reset(const Instance* k, double* s) {
  int i;
  for (i = 0; i < state_size(k); i++) s[i] = 0.0;
  s[S_X_REF] = NAN;
  s[S_P_I] = k->p[P_PNEUMATICS_ATMOSPHERE];
  s[S_P_O] = k->p[P_PNEUMATICS_ATMOSPHERE];
  s[S_INTEGRAL] = k->integral0;
  s[S_REST_PENDING] = k->start_at_rest;
}

/* Plant.rest: regulators settled on the commands, chambers at their set points. */
static void plant_rest(const Instance* k, double* s, double pi_cmd, double po_cmd) {
  double atmosphere = k->p[P_PNEUMATICS_ATMOSPHERE];
  regulator_rest(k, &s[S_PI_REG], queue_i(s), pi_cmd);
  regulator_rest(k, &s[S_PO_REG], queue_o(k, s), po_cmd);
  s[S_P_I] = s[S_PI_REG] + atmosphere;
  s[S_P_O] = s[S_PO_REG] + atmosphere;
}

/* Once a muscle's state has left its range, or its model changed under it, it stops:
   no force, no advance, until mj_resetData. */
static int stopped(const double* s) {
  return ((int)s[S_STATUS] & (WPAM_STATUS_PRESSURE | WPAM_STATUS_MODEL)) != 0;
}

/* ---- the step ---- */

/* The commands of this step from the input channels: each clamped to its actuator's
   ctrlrange where limited (as MuJoCo does for its own actuators); a non-finite one, which
   MuJoCo warns about (mjWARN_BADCTRL), replaced by that channel's last finite value
   (held in the state, 0 at the start); the target held to the stroke. */
static void read_commands(const mjModel* m, const mjData* d, const Instance* k, double* s,
                          double* command) {
  int i;
  for (i = 0; i < k->nchannel; i++) {
    int a = k->channel[i];
    double c = d->ctrl[a];
    if (m->actuator_ctrllimited[a])
      c = py_min(py_max(c, m->actuator_ctrlrange[2 * a]), m->actuator_ctrlrange[2 * a + 1]);
    if (isfinite(c))
      s[S_INPUT0 + i] = c;
    command[i] = s[S_INPUT0 + i];
  }
  if (CONTROL_FEEDBACK[k->control]) command[0] = in_stroke(k, command[0]);
}

/* The friction level [N] of this step into this simulation's friction row of the muscle's
   tendon: the plugin's one write into MuJoCo's constraint data.

   MuJoCo makes a friction row for a tendon whose model frictionloss is positive
   (efc_type mjCNSTR_FRICTION_TENDON, efc_id the tendon) in mj_makeConstraint, and reads
   efc_frictionloss in the constraint solve; mj_fwdActuation, which calls compute, runs
   between the two (MuJoCo 3.x mj_forward: ... mj_makeConstraint, ..., mj_fwdActuation,
   mj_fwdAcceleration, mj_fwdConstraint). So the level written here is the one the solver
   (and the no-slip solver) holds the tendon with this step, for this mjData alone; the
   model's tendon_frictionloss, shared by every simulation of a batch, stays untouched.
   tests/test_plugin.py fails if that order changes. The row keeps its place while the
   constraints before it do; it is looked up again when it moved. */
static void set_friction_level(mjData* d, Instance* k, double level) {
  int row = k->friction_row;
  if (!(row < d->nefc && d->efc_type[row] == mjCNSTR_FRICTION_TENDON
        && d->efc_id[row] == k->tendon)) {
    for (row = 0; row < d->nefc; row++)
      if (d->efc_type[row] == mjCNSTR_FRICTION_TENDON && d->efc_id[row] == k->tendon) break;
    if (row == d->nefc) return;
    k->friction_row = row;
  }
  d->efc_frictionloss[row] = level;
}

/* No force from a muscle that does not step (its friction row keeps the model's level). */
static void no_force(const mjModel* m, mjData* d, int instance) {
  int i;
  for (i = 0; i < m->nu; i++)
    if (m->actuator_plugin[i] == instance) d->actuator_force[i] = 0.0;
}

/* ---- plugin callbacks ---- */

/* The state size: the named fields and two dead-time queues of round(dead_time / timestep)
   steps at the time step the model compiles with (checked in full by init). */
static int wpam_nstate(const mjModel* m, int instance) {
  double dead_time = 0.0, dt = m->opt.timestep;
  const char* text = mj_getPluginConfig(m, instance, "pneumatics.dead_time");
  static const double PRESET_DEFAULTS[WPAM_NPRESET][P_COUNT] = WPAM_PRESET_DEFAULTS;
  static const char* const PRESETS[] = {WPAM_PRESETS};
  const char* preset_name = mj_getPluginConfig(m, instance, "preset");
  int preset = preset_name ? find_word(preset_name, PRESETS, WPAM_NPRESET) : 0;
  dead_time = PRESET_DEFAULTS[preset > 0 ? preset : 0][P_PNEUMATICS_DEAD_TIME];
  if (text && text[0] && !parse_number(text, &dead_time)) dead_time = 0.0;
  if (!(dt > 0.0) || !(dead_time >= 0.0) || !(dead_time / dt <= WPAM_MAX_QUEUE_STEPS))
    return S_COUNT; /* init refuses the configuration */
  return S_COUNT + 2 * (int)nearbyint(dead_time / dt);
}

/* A new mjData: the instance's configuration read and checked once, into its Instance. */
static int wpam_init(const mjModel* m, mjData* d, int instance) {
  Instance k;
  char err[600];
  uintptr_t h;
  if (derive_for_model(m, instance, &k, err, sizeof(err))) mju_error("%s", err);
  h = new_slot(d, instance, &k);
  if (!h) return -1;
  d->plugin_data[instance] = h;
  return 0;
}

/* Frees d's own Instance, never another data's whose handle a copy holds. */
static void wpam_destroy(mjData* d, int instance) {
  uintptr_t h = d->plugin_data[instance];
  if (!owned(slot(h), d, instance)) h = find_owned(d, instance);
  if (h) free_slot(h);
  d->plugin_data[instance] = 0;
}

/* mj_copyData: dest keeps its own Instance (MuJoCo restores dest's plugin_data); it holds
   what the model determines, which instance_of re-derives if dest steps another model. */
static void wpam_copy(mjData* dest, const mjModel* m, const mjData* src, int instance) {
  (void)dest;
  (void)m;
  (void)src;
  (void)instance;
}

/* mj_resetData: the initial state from the Instance a handle names (any data's: what the
   model determines is the same), or read afresh; never past the state MuJoCo sized. */
static void wpam_reset(const mjModel* m, mjtNum* plugin_state, void* plugin_data,
                       int instance) {
  const Instance* k = slot((uintptr_t)plugin_data);
  Instance fresh;
  char err[600];
  int i;
  if (!(k && k->in_use && k->model == m && k->instance == instance
        && state_size(k) == m->plugin_statenum[instance])) {
    if (derive_for_model(m, instance, &fresh, err, sizeof(err))) {
      for (i = 0; i < m->plugin_statenum[instance]; i++) plugin_state[i] = 0.0;
      plugin_state[S_STATUS] = WPAM_STATUS_MODEL;
      return;
    }
    k = &fresh;
  }
  state_reset(k, plugin_state);
}

/* STATUS_STROKE, and the first time since the data's reset one MuJoCo warning naming the
   tendon range that holds the muscle in its stroke (plugin.tendon_range). */
static void left_stroke(const mjModel* m, int instance, const Instance* k, double* s,
                        double x) {
  double natural = k->length0 + k->contraction0; /* the tendon's length at x = 0 */
  if (!((int)s[S_STATUS] & WPAM_STATUS_STROKE))
    mju_warning("wpam_mj.muscle instance '%s': contraction x = %.6g m left the stroke [0, "
                "%.6g] m by more than %.6g m (status %d); limit its tendon from the full bag "
                "to the natural length: range=\"%.6g %.6g\" (plugin.tendon_range)",
                instance_name(m, instance), x, k->max_contraction, WPAM_STROKE_TOLERANCE,
                WPAM_STATUS_STROKE, natural - k->max_contraction, natural);
  set_status(s, WPAM_STATUS_STROKE);
}

static void wpam_compute(const mjModel* m, mjData* d, int instance, int capability_bit) {
  double* s = d->plugin_state + m->plugin_stateadr[instance];
  Instance* k = instance_of(m, d, instance, s);
  double command[WPAM_MAX_CHANNELS] = {0.0};
  double atmosphere, x, v, x_ref = NAN, pi_cmd, po_cmd, pi_gauge, po_gauge, area, force;
  double friction;
  int i;
  (void)capability_bit;
  if (!k || stopped(s)) {
    no_force(m, d, instance);
    return;
  }
  atmosphere = k->p[P_PNEUMATICS_ATMOSPHERE];
  x = k->contraction0 + (k->length0 - d->ten_length[k->tendon]);
  v = -d->ten_velocity[k->tendon];
  read_commands(m, d, k, s, command);
  if (CONTROL_FEEDBACK[k->control]) {
    double po_ff = k->nchannel > 2 ? command[2] : 0.0;
    double integral_next, derivative, e;
    x_ref = command[0];
    pi_cmd = k->nchannel > 1 ? command[1] : pi_feedforward(k, x_ref);
    po_cmd = feedback_output(k, s, x, x_ref, po_ff, &integral_next, &derivative, &e);
    s[S_NEXT_INTEGRAL] = integral_next;
    s[S_NEXT_DERIVATIVE] = derivative;
    s[S_NEXT_E] = e;
  } else {
    pi_cmd = command[0];
    po_cmd = command[1];
  }
  if (s[S_REST_PENDING] != 0.0) plant_rest(k, s, pi_cmd, po_cmd);
  pi_gauge = s[S_P_I] - atmosphere;
  po_gauge = s[S_P_O] - atmosphere;
  area = area_at(k, x);
  force = kernel_tendon_force(pi_gauge, po_gauge, area, rubber_at(k, x),
                              k->p[P_MUSCLE_OUTPUT_COEFF], k->p[P_MUSCLE_AXIAL_AREA], k->guided);
  friction = kernel_friction_level(pi_gauge, po_gauge, area, k->p[P_MUSCLE_FRICTION_COEFF],
                                   k->p[P_MUSCLE_FRICTION_CONST]);
  if (!(-WPAM_STROKE_TOLERANCE <= x && x <= k->max_contraction + WPAM_STROKE_TOLERANCE))
    left_stroke(m, instance, k, s, x);
  if (!isfinite(x)) { /* MuJoCo's state is already bad: add nothing to it */
    force = 0.0;
    friction = k->p[P_MUSCLE_FRICTION_CONST];
  }

  s[S_X] = x;
  s[S_VELOCITY] = v;
  s[S_X_REF] = x_ref;
  s[S_PI] = pi_gauge;
  s[S_PO] = po_gauge;
  s[S_PI_CMD] = pi_cmd;
  s[S_PO_CMD] = po_cmd;
  s[S_TENSION] = force;
  s[S_FRICTION] = friction;

  d->actuator_force[k->channel[0]] = -force; /* along the tendon's length */
  for (i = 1; i < k->nchannel; i++) d->actuator_force[k->channel[i]] = 0.0;
  set_friction_level(d, k, friction);
}

static void wpam_advance(const mjModel* m, mjData* d, int instance) {
  double* s = d->plugin_state + m->plugin_stateadr[instance];
  Instance* k = instance_of(m, d, instance, s);
  double atmosphere, x, set_i, set_o, area, vol, v, m_i, m_o;
  int head;
  if (!k || stopped(s)) return;
  atmosphere = k->p[P_PNEUMATICS_ATMOSPHERE];
  head = (int)s[S_HEAD];
  if (CONTROL_FEEDBACK[k->control]) { /* PoFeedback.update's commit */
    s[S_INTEGRAL] = s[S_NEXT_INTEGRAL];
    s[S_DERIVATIVE] = s[S_NEXT_DERIVATIVE];
    s[S_E_PREV] = s[S_NEXT_E];
    s[S_HAS_PREV] = 1.0;
  }
  s[S_REST_PENDING] = 0.0;
  /* Plant.step: regulators, then chambers (volumes held to the stroke) */
  set_i = regulator_update(k, &s[S_PI_REG], queue_i(s), head, s[S_PI_CMD]);
  set_o = regulator_update(k, &s[S_PO_REG], queue_o(k, s), head, s[S_PO_CMD]);
  if (k->delay_steps) s[S_HEAD] = (head + 1) % k->delay_steps;
  v = s[S_VELOCITY];
  x = in_stroke(k, s[S_X]);
  area = area_at(k, x);
  vol = volume_at(k, x);
  m_i = regulator_flow(k, set_i, s[S_P_I], k->p[P_PNEUMATICS_INNER_CONDUCTANCE]);
  m_o = regulator_flow(k, set_o, s[S_P_O], k->p[P_PNEUMATICS_OUTER_CONDUCTANCE]);
  s[S_P_I] = kernel_chamber_step(s[S_P_I], m_i,
                                 kernel_inner_volume(vol, k->p[P_PNEUMATICS_TUBE_VOLUME]),
                                 area, v, k->p[P_PNEUMATICS_POLYTROPIC_INDEX], k->dt);
  /* no outer bag (rlam, mckibben): the atmosphere, exactly */
  s[S_P_O] = kernel_outer_chamber_step(k->outer_chamber, s[S_P_O], m_o, vol, x, area,
                                       k->p[P_MUSCLE_AXIAL_AREA], k->bag_volume,
                                       k->p[P_PNEUMATICS_TUBE_VOLUME], v,
                                       k->p[P_PNEUMATICS_POLYTROPIC_INDEX], k->dt, atmosphere);
  if (!(s[S_P_I] > 0.0 && s[S_P_O] > 0.0 && isfinite(s[S_P_I]) && isfinite(s[S_P_O])))
    set_status(s, WPAM_STATUS_PRESSURE);
}

/* 1 when the headers this file was compiled with match the loaded libmujoco. */
int wpam_abi_ok(void) { return mj_version() == mjVERSION_HEADER; }

/* The generated tables' fingerprint, checked by wpam_mj/simulation/plugin.py when it loads us. */
const char* wpam_tables_hash(void) { return WPAM_TABLES_HASH; }

mjPLUGIN_LIB_INIT(wpam_muscle) {
  mjpPlugin plugin;
  mjp_defaultPlugin(&plugin);
  plugin.name = "wpam_mj.muscle";
  plugin.capabilityflags |= mjPLUGIN_ACTUATOR;
  plugin.nattribute = NATTRIBUTE;
  plugin.attributes = ATTRIBUTES;
  plugin.nstate = wpam_nstate;
  plugin.init = wpam_init;
  plugin.destroy = wpam_destroy;
  plugin.copy = wpam_copy;
  plugin.reset = wpam_reset;
  plugin.compute = wpam_compute;
  plugin.advance = wpam_advance;
  mjp_registerPlugin(&plugin);
}
