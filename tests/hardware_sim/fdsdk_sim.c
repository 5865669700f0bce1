/* A simulated Force Dimension SDK (libdrd / libdhd) for the tests of arsurf's adapter.
 *
 * It exports, with the SDK's C signatures (as forcedimension-core declares them with ctypes),
 * the functions the adapter calls, and simulates one omega.3 on USB: a mass-spring handle
 * (sim_handle.h) advanced on the wall clock at every call, motors saturating at 12 N, the
 * encoder range and kinematics the SDK reports, the SDK-side force limit (dhdSetMaxForce), the
 * firmware watchdog (dhdSetWatchdog: no force command for that long -> forces off), DRD
 * calibration (drdIsInitialized / drdAutoInit) and a device that disappears (sim_unplug: every
 * call fails with DHD_ERROR_COM). Every other symbol the binding binds comes from a generated
 * stub file and fails with DHD_ERROR_NOT_IMPLEMENTED.
 *
 * Held to the vendor's rules, not to what an adapter may expect:
 * - Expert API. dhdc.h lists dhdSetWatchdog/dhdGetWatchdog, dhdGetEncRange and the
 *   dhdDelta{EncoderToPosition,PositionToEncoder} kinematics under "expert API", and every vendor
 *   example calls dhdEnableExpertMode() before them: without it they fail here with
 *   DHD_ERROR_EXPERT_MODE_DISABLED (expert mode is one library-wide switch, as in the SDK).
 * - DRD. The robotic SDK's calls (drdIsSupported, drdIsInitialized, drdAutoInit, drdStop) act on
 *   a device the DRD opened (drdOpen / drdOpenID, closed by drdClose), as in the vendor's
 *   autoinit example; on a device opened with dhdOpen only they fail (drdIsSupported: false).
 * - Watchdog. A firmware without it (sim_reset's has_watchdog = 0) answers dhdSetWatchdog with
 *   DHD_ERROR_NOT_AVAILABLE.
 * - Kinematics. Not a box: encoder 0 turns the handle's azimuth, encoder 1 its radius, encoder 2
 *   its height, so the reachable set is a cylinder (radius RADIUS, height HEIGHT, as the vendor's
 *   datasheets give the workspace) whose bounding box's corners cannot be reached;
 *   dhdDeltaPositionToEncoder answers any point, with encoders outside dhdGetEncRange for a point
 *   the handle cannot reach (the caller must check the range).
 *
 * The vendor frame is the SDK's: metres and newtons, x towards the operator, y to the right, z up.
 * Functions named sim_* are the test's hooks. */
#include <stdio.h>
#include <string.h>
#include <stdbool.h>
#include "sim_handle.h"

#define DHD_NO_ERROR 0
#define DHD_ERROR_COM 2
#define DHD_ERROR_NO_DEVICE_FOUND 5
#define DHD_ERROR_NOT_AVAILABLE 6
#define DHD_ERROR_TIMEOUT 7
#define DHD_ERROR_EXPERT_MODE_DISABLED 9
#define DHD_ERROR_NOT_IMPLEMENTED 10
#define DHD_ERROR_INVALID_INDEX 15
#define DHD_MOTOR_SATURATED 2
#define MAX_DOF 8
#define ENC_UNIT 1e-5   /* m per count of the radius and height encoders */
#define ENC_RAD 1e-4    /* rad per count of the azimuth encoder */
#define RADIUS 0.07     /* m: the reachable cylinder's radius ... */
#define HEIGHT 0.12     /* m: ... and height, centred on the origin */

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static __thread int last_error = DHD_NO_ERROR;
static sim_handle H;
static int inited = 0, plugged = 1, opened = 0, force_on = 0, calibrated = 1, kinematics = 1;
static int device_type = 33; /* DHD_DEVICE_OMEGA3 */
static int expert = 0, drd_opened = 0, has_watchdog = 1;
static long n_expert_refused = 0, n_drd_refused = 0;
static double sdk_cap = -1.0, watchdog = 0.0, t_last_force = 0.0, t_origin = 0.0;
static double commanded[3];
static long n_set_force = 0, n_get_position = 0, n_autoinit = 0, watchdog_trips = 0, n_saturated = 0;
static double max_norm_commanded = 0.0, max_norm_applied = 0.0;
int sim_unimplemented(void) { last_error = DHD_ERROR_NOT_IMPLEMENTED; return -1; }

static void init_once(void) {
    if (!inited) { sim_handle_init(&H, 12.0); t_origin = sim_clock(); inited = 1; }
}
static double now(void) { return sim_clock() - t_origin; }

/* advance the physics to now, applying the watchdog; caller holds the lock */
static void advance(void) {
    init_once();
    double t = now();
    if (watchdog > 0 && force_on && t - t_last_force > watchdog && (H.f[0] != 0 || H.f[1] != 0 || H.f[2] != 0)) {
        double zero[3] = {0, 0, 0};
        sim_handle_advance(&H, t_last_force + watchdog);
        sim_handle_force(&H, zero);
        watchdog_trips++;
    }
    sim_handle_advance(&H, t);
}
static int usable(char id) {
    if (!plugged) { last_error = DHD_ERROR_COM; return 0; }
    if (!opened || (id != 0 && id != -1)) { last_error = DHD_ERROR_INVALID_INDEX; return 0; }
    return 1;
}
#define ENTER(id) pthread_mutex_lock(&lock); if (!usable(id)) { pthread_mutex_unlock(&lock); return -1; } advance()
#define LEAVE(v) do { pthread_mutex_unlock(&lock); return (v); } while (0)
/* an expert-API call without dhdEnableExpertMode fails, as in the SDK */
#define EXPERT() if (!expert) { last_error = DHD_ERROR_EXPERT_MODE_DISABLED; n_expert_refused++; LEAVE(-1); }
/* a DRD call on a device the DRD did not open fails */
#define DRD() if (!drd_opened) { last_error = DHD_ERROR_INVALID_INDEX; n_drd_refused++; LEAVE(-1); }

int dhdEnableExpertMode(void) { pthread_mutex_lock(&lock); expert = 1; pthread_mutex_unlock(&lock); return 0; }
int dhdDisableExpertMode(void) { pthread_mutex_lock(&lock); expert = 0; pthread_mutex_unlock(&lock); return 0; }

/* ---- SDK: library and device selection ---------------------------------------------------- */
void dhdGetSDKVersion(int *major, int *minor, int *release, int *revision) {
    *major = 3; *minor = 17; *release = 0; *revision = 0;
}
int dhdErrorGetLast(void) { return last_error; }
const char *dhdErrorGetStr(int e) {
    switch (e) {
    case DHD_NO_ERROR: return "no error";
    case DHD_ERROR_COM: return "communication error between the host and the haptic device";
    case DHD_ERROR_NO_DEVICE_FOUND: return "no compatible Force Dimension device found";
    case DHD_ERROR_TIMEOUT: return "timeout";
    case DHD_ERROR_EXPERT_MODE_DISABLED: return "expert mode is disabled";
    case DHD_ERROR_NOT_IMPLEMENTED: return "feature not implemented";
    case DHD_ERROR_INVALID_INDEX: return "invalid index";
    default: return "error";
    }
}
const char *dhdErrorGetLastStr(void) { return dhdErrorGetStr(last_error); }
int dhdGetDeviceCount(void) { return plugged ? 1 : 0; }
int dhdGetAvailableCount(void) { return (plugged && !opened) ? 1 : 0; }
static int open_device(int by_drd) {
    pthread_mutex_lock(&lock);
    init_once();
    if (!plugged) { last_error = DHD_ERROR_NO_DEVICE_FOUND; pthread_mutex_unlock(&lock); return -1; }
    opened = 1; drd_opened = by_drd; force_on = 0; sdk_cap = -1.0; watchdog = 0.0;
    pthread_mutex_unlock(&lock);
    return 0;
}
int dhdOpen(void) { return open_device(0); }
int dhdOpenID(char index) {
    if (index != 0) { last_error = DHD_ERROR_INVALID_INDEX; return -1; }
    return open_device(0);
}
int drdOpen(void) { return open_device(1); }
int drdOpenID(char index) {
    if (index != 0) { last_error = DHD_ERROR_INVALID_INDEX; return -1; }
    return open_device(1);
}
int dhdClose(char id) {
    pthread_mutex_lock(&lock);
    double zero[3] = {0, 0, 0};
    if (inited) { advance(); sim_handle_force(&H, zero); }
    opened = 0; drd_opened = 0; force_on = 0;
    pthread_mutex_unlock(&lock);
    return plugged ? 0 : -1;
}
int drdClose(char id) { return dhdClose(id); }
int dhdGetSystemType(char id) { ENTER(id); LEAVE(device_type); }
const char *dhdGetSystemName(char id) {
    if (!plugged || !opened) { last_error = DHD_ERROR_COM; return NULL; }
    return device_type == 60 ? "falcon" : "omega.3";
}
int dhdGetSerialNumber(unsigned short *sn, char id) { ENTER(id); *sn = 4242; LEAVE(0); }
int dhdEnableForce(bool enable, char id) { ENTER(id); force_on = enable; t_last_force = now(); LEAVE(0); }
int dhdStop(char id) {
    ENTER(id);
    double zero[3] = {0, 0, 0};
    sim_handle_force(&H, zero); force_on = 0;
    LEAVE(0);
}

/* ---- SDK: state and forces ------------------------------------------------------------------ */
int dhdGetPosition(double *px, double *py, double *pz, char id) {
    ENTER(id);
    n_get_position++;
    *px = H.x[0]; *py = H.x[1]; *pz = H.x[2];
    LEAVE(0);
}
int dhdConfigLinearVelocity(int ms, int mode, char id) { ENTER(id); LEAVE(0); }
int dhdGetLinearVelocity(double *vx, double *vy, double *vz, char id) {
    ENTER(id);
    *vx = H.v[0]; *vy = H.v[1]; *vz = H.v[2];
    LEAVE(0);
}
unsigned int dhdGetButtonMask(char id) {
    if (!plugged) { last_error = DHD_ERROR_COM; return 0; }
    return 0;
}
int dhdSetForce(double fx, double fy, double fz, char id) {
    ENTER(id);
    double f[3] = {fx, fy, fz};
    double n = sqrt(fx * fx + fy * fy + fz * fz);
    n_set_force++;
    commanded[0] = fx; commanded[1] = fy; commanded[2] = fz;
    if (n > max_norm_commanded) max_norm_commanded = n;
    if (sdk_cap >= 0 && n > sdk_cap) for (int a = 0; a < 3; a++) f[a] *= sdk_cap / n;
    if (!force_on) for (int a = 0; a < 3; a++) f[a] = 0;
    int sat = sim_handle_force(&H, f);
    n_saturated += sat;
    double na = sqrt(H.f[0] * H.f[0] + H.f[1] * H.f[1] + H.f[2] * H.f[2]);
    if (na > max_norm_applied) max_norm_applied = na;
    t_last_force = now();
    LEAVE(sat ? DHD_MOTOR_SATURATED : 0);
}
int dhdGetForce(double *fx, double *fy, double *fz, char id) {
    ENTER(id);
    *fx = H.f[0]; *fy = H.f[1]; *fz = H.f[2];
    LEAVE(0);
}
double dhdGetMaxForce(char id) { return plugged ? sdk_cap : -1.0; }
int dhdSetMaxForce(double limit, char id) { ENTER(id); sdk_cap = limit; LEAVE(0); }
int dhdSetWatchdog(unsigned char units, char id) {
    ENTER(id);
    EXPERT();
    if (!has_watchdog) { last_error = DHD_ERROR_NOT_AVAILABLE; LEAVE(-1); }
    watchdog = units * 125e-6;
    LEAVE(0);
}
int dhdGetWatchdog(unsigned char *units, char id) {
    ENTER(id);
    EXPERT();
    if (!has_watchdog) { last_error = DHD_ERROR_NOT_AVAILABLE; LEAVE(-1); }
    *units = (unsigned char)lround(watchdog / 125e-6);
    LEAVE(0);
}

/* ---- SDK: kinematics the device reports ----------------------------------------------------- */
/* encoder ranges: azimuth -pi..pi, radius 0..RADIUS, height -HEIGHT/2..HEIGHT/2 */
static const int ENC_MIN[3] = {-31416, 0, -6000}, ENC_MAX[3] = {31416, 7000, 6000};
int dhdGetEncRange(int *emin, int *emax, char id) {
    ENTER(id);
    EXPERT();
    if (!kinematics) { last_error = DHD_ERROR_NOT_AVAILABLE; LEAVE(-1); }
    for (int a = 0; a < MAX_DOF; a++) { emin[a] = a < 3 ? ENC_MIN[a] : 0; emax[a] = a < 3 ? ENC_MAX[a] : 0; }
    LEAVE(0);
}
int dhdDeltaEncoderToPosition(int e0, int e1, int e2, double *px, double *py, double *pz, char id) {
    ENTER(id);
    EXPERT();
    if (!kinematics) { last_error = DHD_ERROR_NOT_AVAILABLE; LEAVE(-1); }
    double phi = e0 * ENC_RAD, r = e1 * ENC_UNIT;
    *px = r * cos(phi); *py = r * sin(phi); *pz = e2 * ENC_UNIT;
    LEAVE(0);
}
int dhdDeltaPositionToEncoder(double px, double py, double pz, int *e0, int *e1, int *e2, char id) {
    ENTER(id);
    EXPERT();
    if (!kinematics) { last_error = DHD_ERROR_NOT_AVAILABLE; LEAVE(-1); }
    *e0 = (int)lround(atan2(py, px) / ENC_RAD); *e1 = (int)lround(hypot(px, py) / ENC_UNIT);
    *e2 = (int)lround(pz / ENC_UNIT);
    LEAVE(0);
}

/* ---- DRD: calibration ------------------------------------------------------------------------ */
bool drdIsSupported(char id) {
    pthread_mutex_lock(&lock);
    if (opened && !drd_opened) { last_error = DHD_ERROR_INVALID_INDEX; n_drd_refused++; }
    bool ok = plugged && opened && drd_opened && device_type != 60;
    pthread_mutex_unlock(&lock);
    return ok;
}
bool drdIsInitialized(char id) {
    pthread_mutex_lock(&lock);
    if (opened && !drd_opened) { last_error = DHD_ERROR_INVALID_INDEX; n_drd_refused++; }
    bool ok = plugged && opened && drd_opened && calibrated;
    pthread_mutex_unlock(&lock);
    return ok;
}
int drdAutoInit(char id) {
    ENTER(id);
    DRD();
    n_autoinit++;
    calibrated = 1;
    for (int a = 0; a < 3; a++) { H.x[a] = 0; H.v[a] = 0; }
    LEAVE(0);
}
int drdStop(bool frc, char id) { ENTER(id); DRD(); force_on = frc; LEAVE(0); }

/* ---- OS-independent helpers of the SDK -------------------------------------------------------- */
double dhdGetTime(void) { init_once(); return now(); }

/* ---- test hooks ------------------------------------------------------------------------------- */
void sim_reset(int type, int is_calibrated, int has_kinematics, int with_watchdog) {
    pthread_mutex_lock(&lock);
    inited = 0; init_once();
    device_type = type; calibrated = is_calibrated; kinematics = has_kinematics; has_watchdog = with_watchdog;
    plugged = 1; opened = 0; drd_opened = 0; expert = 0; force_on = 0; sdk_cap = -1.0; watchdog = 0.0;
    n_set_force = n_get_position = n_autoinit = watchdog_trips = n_saturated = 0;
    n_expert_refused = n_drd_refused = 0;
    max_norm_commanded = max_norm_applied = 0.0;
    commanded[0] = commanded[1] = commanded[2] = 0.0;
    pthread_mutex_unlock(&lock);
}
void sim_set_hand(const double *p0, const double *amp, double freq, double k, double b) {
    pthread_mutex_lock(&lock);
    init_once(); advance();
    for (int a = 0; a < 3; a++) { H.p0[a] = p0[a]; H.amp[a] = amp[a]; }
    H.freq = freq; H.kh = k; H.bh = b;
    pthread_mutex_unlock(&lock);
}
void sim_place(const double *x) {
    pthread_mutex_lock(&lock);
    init_once(); advance();
    for (int a = 0; a < 3; a++) { H.x[a] = x[a]; H.v[a] = 0; }
    pthread_mutex_unlock(&lock);
}
void sim_unplug(void) { pthread_mutex_lock(&lock); plugged = 0; pthread_mutex_unlock(&lock); }
/* state: x(3) v(3) applied force(3) commanded force(3) */
void sim_state(double *out) {
    pthread_mutex_lock(&lock);
    if (inited && plugged) advance();
    for (int a = 0; a < 3; a++) { out[a] = H.x[a]; out[3 + a] = H.v[a]; out[6 + a] = H.f[a]; out[9 + a] = commanded[a]; }
    pthread_mutex_unlock(&lock);
}
/* counters: set_force calls, get_position calls, autoinit calls, watchdog trips, saturations,
 * largest commanded and applied force norms, SDK cap, watchdog (s), force enabled, opened,
 * expert mode on, expert calls refused, DRD calls refused, opened by the DRD */
void sim_counters(double *out) {
    pthread_mutex_lock(&lock);
    out[0] = n_set_force; out[1] = n_get_position; out[2] = n_autoinit; out[3] = watchdog_trips;
    out[4] = n_saturated; out[5] = max_norm_commanded; out[6] = max_norm_applied; out[7] = sdk_cap;
    out[8] = watchdog; out[9] = force_on; out[10] = opened;
    out[11] = expert; out[12] = n_expert_refused; out[13] = n_drd_refused; out[14] = drd_opened;
    pthread_mutex_unlock(&lock);
}
