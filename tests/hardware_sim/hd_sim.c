/* A simulated OpenHaptics HD library (libHD.so) for the tests of arsurf's adapter.
 *
 * It exports, with the HD API's C signatures, the functions pyOpenHaptics and the adapter call,
 * and simulates one Touch: a mass-spring handle (sim_handle.h) advanced by the HD servo
 * scheduler, a thread that runs the scheduled callbacks every 1 ms like the real one. HD units:
 * millimetres, mm/s, newtons; HD frame: x right, y up, z towards the operator; the 4x4 transform
 * is column-major with the translation in elements 12-14. Forces set with hdSetDoublev
 * (HD_CURRENT_FORCE) inside a frame are applied at hdEndFrame when HD_FORCE_OUTPUT is enabled,
 * clamped to the nominal maximum when HD_MAX_FORCE_CLAMPING is. Errors go on a stack that
 * hdGetError pops. sim_unplug makes every later frame fail with HD_COMM_ERROR and freezes the
 * readings, as a device whose cable was pulled. Functions named sim_* are the test's hooks.
 *
 * Held to the vendor's rules (OpenHaptics Programmer's Guide and its Calibration example):
 * - hdUpdateCalibration is called from a scheduled callback (the example's
 *   UpdateCalibrationCallback, run by hdScheduleSynchronous); called from any other thread while
 *   the servo runs, it fails with HD_INVALID_OPERATION and does nothing. The styles the device
 *   supports are HD_CALIBRATION_STYLE (sim_reset's style); a style it does not support fails with
 *   HD_INVALID_VALUE.
 * - HD_CALIBRATION_ENCODER_RESET zeroes the encoders where the arm is: an arm not held in its
 *   reset position reads offset by that much from then on (sim_reset puts the reset position at
 *   the origin).
 * - The servo thread is a C thread calling the callbacks; it records how long each asynchronous
 *   callback took (sim_callback_times), so a test sees a callback that waits, e.g. for Python's GIL. */
#include <stdbool.h>
#include <string.h>
#include <unistd.h>
#include "sim_handle.h"

typedef unsigned int HHD;
typedef unsigned int HDenum;
typedef unsigned int HDCallbackCode;
typedef unsigned long HDSchedulerHandle;
typedef HDCallbackCode (*HDSchedulerCallback)(void *);
typedef struct { unsigned int errorCode; int internalErrorCode; HHD hHD; } HDErrorInfo;

#define HD_SUCCESS 0x000
#define HD_INVALID_ENUM 0x0100
#define HD_INVALID_VALUE 0x0102
#define HD_INVALID_OPERATION 0x0103
#define HD_EXCEEDED_MAX_FORCE 0x0201
#define HD_DEVICE_FAULT 0x0300
#define HD_COMM_ERROR 0x0302
#define HD_INVALID_HANDLE 0xFFFFFFFFu
#define HD_CALLBACK_DONE 0
#define HD_CURRENT_BUTTONS 0x2000
#define HD_CURRENT_POSITION 0x2050
#define HD_CURRENT_VELOCITY 0x2051
#define HD_CURRENT_TRANSFORM 0x2052
#define HD_DEVICE_MODEL_TYPE 0x2501
#define HD_DEVICE_VENDOR 0x2503
#define HD_DEVICE_SERIAL_NUMBER 0x2504
#define HD_MAX_WORKSPACE_DIMENSIONS 0x2550
#define HD_USABLE_WORKSPACE_DIMENSIONS 0x2551
#define HD_CALIBRATION_STYLE 0x2555
#define HD_UPDATE_RATE 0x2600
#define HD_NOMINAL_MAX_STIFFNESS 0x2602
#define HD_NOMINAL_MAX_FORCE 0x2603
#define HD_NOMINAL_MAX_CONTINUOUS_FORCE 0x2604
#define HD_NOMINAL_MAX_DAMPING 0x2609
#define HD_CURRENT_FORCE 0x2700
#define HD_FORCE_OUTPUT 0x4000
#define HD_MAX_FORCE_CLAMPING 0x4001
#define HD_CALIBRATION_OK 0x5000
#define HD_CALIBRATION_NEEDS_UPDATE 0x5001
#define HD_CALIBRATION_NEEDS_MANUAL_INPUT 0x5002
#define HD_CALIBRATION_ENCODER_RESET 1
#define HD_CALIBRATION_AUTO 2
#define HD_CALIBRATION_INKWELL 4
#define MAX_CB 16

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t done_cv = PTHREAD_COND_INITIALIZER;
static sim_handle H;
static const double usable[6] = {-80, -60, -35, 80, 60, 35}; /* mm: min x, y, z, max x, y, z */
static const double nominal_force = 3.3, continuous_force = 0.88, stiffness = 1.26, damping = 0.002;
static int initialized = 0, plugged = 1, force_output = 0, clamping = 0, running = 0, in_frame = 0;
static int calibration = HD_CALIBRATION_OK, calibration_style = HD_CALIBRATION_INKWELL;
static double cal_offset[3]; /* m: where the encoders were zeroed (encoder reset), HD frame */
static long n_update_refused = 0;
#define N_TIMES 8192
static double cb_times[N_TIMES]; /* s: duration of the last asynchronous callbacks */
static long n_times = 0;
static double t_origin = 0, frame_x[3], frame_v[3], pending[3];
static int pending_set = 0;
static unsigned int errors[16];
static int n_errors = 0;
static struct { HDSchedulerCallback cb; void *data; int used, sync, done; } cbs[MAX_CB];
static pthread_t servo;
static long n_frames = 0, n_calibrations = 0;
static double max_commanded = 0, max_applied = 0;

static void push_error(unsigned int code) { if (n_errors < 16) errors[n_errors++] = code; }
static double now(void) { return sim_clock() - t_origin; }

/* ---- device ------------------------------------------------------------------------------- */
HHD hdInitDevice(const char *name) {
    pthread_mutex_lock(&lock);
    if (!plugged) { push_error(HD_DEVICE_FAULT); pthread_mutex_unlock(&lock); return HD_INVALID_HANDLE; }
    initialized = 1;
    pthread_mutex_unlock(&lock);
    return 0;
}
void hdDisableDevice(HHD h) { pthread_mutex_lock(&lock); initialized = 0; force_output = 0; pthread_mutex_unlock(&lock); }
HHD hdGetCurrentDevice(void) { return initialized ? 0 : HD_INVALID_HANDLE; }
void hdMakeCurrentDevice(HHD h) {}
HDErrorInfo hdGetError(void) {
    HDErrorInfo e = {HD_SUCCESS, 0, 0};
    pthread_mutex_lock(&lock);
    if (n_errors > 0) { e.errorCode = errors[0]; memmove(errors, errors + 1, (--n_errors) * sizeof errors[0]); }
    pthread_mutex_unlock(&lock);
    return e;
}
void hdEnable(HDenum cap) {
    pthread_mutex_lock(&lock);
    if (cap == HD_FORCE_OUTPUT) force_output = 1; else if (cap == HD_MAX_FORCE_CLAMPING) clamping = 1;
    pthread_mutex_unlock(&lock);
}
void hdDisable(HDenum cap) {
    pthread_mutex_lock(&lock);
    if (cap == HD_FORCE_OUTPUT) force_output = 0; else if (cap == HD_MAX_FORCE_CLAMPING) clamping = 0;
    pthread_mutex_unlock(&lock);
}
const char *hdGetString(HDenum what) {
    switch (what) {
    case HD_DEVICE_MODEL_TYPE: return "Touch";
    case HD_DEVICE_VENDOR: return "3D Systems";
    case HD_DEVICE_SERIAL_NUMBER: return "SIM-0001";
    default: push_error(HD_INVALID_ENUM); return "";
    }
}

/* ---- frames -------------------------------------------------------------------------------- */
void hdBeginFrame(HHD h) {
    pthread_mutex_lock(&lock);
    in_frame = 1; pending_set = 0;
    if (plugged) {
        sim_handle_advance(&H, now());
        for (int a = 0; a < 3; a++) { frame_x[a] = H.x[a]; frame_v[a] = H.v[a]; }
    }
    n_frames++;
    pthread_mutex_unlock(&lock);
}
void hdEndFrame(HHD h) {
    pthread_mutex_lock(&lock);
    in_frame = 0;
    if (!plugged) { push_error(HD_COMM_ERROR); pthread_mutex_unlock(&lock); return; }
    if (pending_set) {
        double f[3] = {0, 0, 0};
        double n = sqrt(pending[0] * pending[0] + pending[1] * pending[1] + pending[2] * pending[2]);
        if (n > max_commanded) max_commanded = n;
        if (force_output) {
            for (int a = 0; a < 3; a++) f[a] = pending[a];
            if (n > nominal_force) {
                if (clamping) for (int a = 0; a < 3; a++) f[a] *= nominal_force / n;
                else { push_error(HD_EXCEEDED_MAX_FORCE); f[0] = f[1] = f[2] = 0; }
            }
        }
        sim_handle_force(&H, f);
        double na = sqrt(H.f[0] * H.f[0] + H.f[1] * H.f[1] + H.f[2] * H.f[2]);
        if (na > max_applied) max_applied = na;
    }
    pthread_mutex_unlock(&lock);
}

/* ---- state ------------------------------------------------------------------------------- */
void hdGetDoublev(HDenum what, double *v) {
    pthread_mutex_lock(&lock);
    switch (what) {
    case HD_CURRENT_POSITION: for (int a = 0; a < 3; a++) v[a] = 1e3 * (frame_x[a] - cal_offset[a]); break;
    case HD_CURRENT_VELOCITY: for (int a = 0; a < 3; a++) v[a] = 1e3 * frame_v[a]; break;
    case HD_CURRENT_TRANSFORM:
        memset(v, 0, 16 * sizeof(double));
        v[0] = v[5] = v[10] = v[15] = 1.0;
        for (int a = 0; a < 3; a++) v[12 + a] = 1e3 * (frame_x[a] - cal_offset[a]);
        break;
    case HD_CURRENT_FORCE: for (int a = 0; a < 3; a++) v[a] = H.f[a]; break;
    case HD_USABLE_WORKSPACE_DIMENSIONS: for (int k = 0; k < 6; k++) v[k] = usable[k]; break;
    case HD_MAX_WORKSPACE_DIMENSIONS: for (int k = 0; k < 6; k++) v[k] = 1.4 * usable[k]; break;
    case HD_NOMINAL_MAX_FORCE: v[0] = nominal_force; break;
    case HD_NOMINAL_MAX_CONTINUOUS_FORCE: v[0] = continuous_force; break;
    case HD_NOMINAL_MAX_STIFFNESS: v[0] = stiffness; break;
    case HD_NOMINAL_MAX_DAMPING: v[0] = damping; break;
    case HD_UPDATE_RATE: v[0] = 1000.0; break;
    default: push_error(HD_INVALID_ENUM);
    }
    pthread_mutex_unlock(&lock);
}
void hdGetIntegerv(HDenum what, int *v) {
    switch (what) {
    case HD_CURRENT_BUTTONS: v[0] = 0; break;
    case HD_CALIBRATION_STYLE: v[0] = calibration_style; break;
    case HD_UPDATE_RATE: v[0] = 1000; break;
    default: push_error(HD_INVALID_ENUM);
    }
}
void hdSetDoublev(HDenum what, const double *v) {
    pthread_mutex_lock(&lock);
    if (what == HD_CURRENT_FORCE) {
        if (!in_frame) push_error(HD_INVALID_OPERATION);
        else { for (int a = 0; a < 3; a++) pending[a] = v[a]; pending_set = 1; }
    } else push_error(HD_INVALID_ENUM);
    pthread_mutex_unlock(&lock);
}

/* ---- calibration --------------------------------------------------------------------------- */
HDenum hdCheckCalibration(void) { return calibration; }
void hdUpdateCalibration(HDenum style) {
    pthread_mutex_lock(&lock);
    if (running && !pthread_equal(pthread_self(), servo)) {
        push_error(HD_INVALID_OPERATION); n_update_refused++;  /* not from a scheduled callback */
    } else if (!(style & calibration_style) || (style & (style - 1))) {
        push_error(HD_INVALID_VALUE); n_update_refused++;
    } else if (calibration == HD_CALIBRATION_NEEDS_UPDATE) {
        if (style == HD_CALIBRATION_ENCODER_RESET) for (int a = 0; a < 3; a++) cal_offset[a] = H.x[a];
        calibration = HD_CALIBRATION_OK; n_calibrations++;
    }
    pthread_mutex_unlock(&lock);
}

/* ---- the servo scheduler: a 1 kHz thread running the callbacks --------------------------------- */
static void run_callbacks(void) {
    for (int k = 0; k < MAX_CB; k++) {
        pthread_mutex_lock(&lock);
        int used = cbs[k].used;
        HDSchedulerCallback cb = cbs[k].cb;
        void *data = cbs[k].data;
        pthread_mutex_unlock(&lock);
        if (!used) continue;
        double t0 = sim_clock();
        HDCallbackCode code = cb(data);
        double dt = sim_clock() - t0;
        pthread_mutex_lock(&lock);
        if (!cbs[k].sync) cb_times[n_times++ % N_TIMES] = dt;
        if (cbs[k].sync || code == HD_CALLBACK_DONE) {
            cbs[k].used = 0; cbs[k].done = 1;
            pthread_cond_broadcast(&done_cv);
        }
        pthread_mutex_unlock(&lock);
    }
}
static void *servo_main(void *arg) {
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    while (1) {
        pthread_mutex_lock(&lock);
        int go = running;
        pthread_mutex_unlock(&lock);
        if (!go) break;
        run_callbacks();
        next.tv_nsec += 1000000;
        if (next.tv_nsec >= 1000000000) { next.tv_nsec -= 1000000000; next.tv_sec++; }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL);
    }
    return NULL;
}
void hdStartScheduler(void) {
    pthread_mutex_lock(&lock);
    if (!running) { running = 1; pthread_create(&servo, NULL, servo_main, NULL); }
    pthread_mutex_unlock(&lock);
}
void hdStopScheduler(void) {
    pthread_mutex_lock(&lock);
    int was = running;
    running = 0;
    pthread_mutex_unlock(&lock);
    if (was) pthread_join(servo, NULL);
}
static int add_callback(HDSchedulerCallback cb, void *data, int sync) {
    pthread_mutex_lock(&lock);
    for (int k = 0; k < MAX_CB; k++)
        if (!cbs[k].used) {
            cbs[k].cb = cb; cbs[k].data = data; cbs[k].used = 1; cbs[k].sync = sync; cbs[k].done = 0;
            pthread_mutex_unlock(&lock);
            return k;
        }
    pthread_mutex_unlock(&lock);
    return -1;
}
HDSchedulerHandle hdScheduleAsynchronous(HDSchedulerCallback cb, void *data, unsigned short priority) {
    return (HDSchedulerHandle)(add_callback(cb, data, 0) + 1);
}
void hdScheduleSynchronous(HDSchedulerCallback cb, void *data, unsigned short priority) {
    pthread_mutex_lock(&lock);
    int go = running;
    pthread_mutex_unlock(&lock);
    if (!go) { cb(data); return; }
    int k = add_callback(cb, data, 1);
    if (k < 0) return;
    pthread_mutex_lock(&lock);
    while (!cbs[k].done) pthread_cond_wait(&done_cv, &lock);
    pthread_mutex_unlock(&lock);
}
void hdUnschedule(HDSchedulerHandle h) {
    pthread_mutex_lock(&lock);
    if (h >= 1 && h <= MAX_CB) cbs[h - 1].used = 0;
    pthread_mutex_unlock(&lock);
}
void hdWaitForCompletion(HDSchedulerHandle h, unsigned int param) {}

/* ---- test hooks (SI units, HD axes) ------------------------------------------------------------- */
void sim_reset(int calibration_status, int style) {
    hdStopScheduler();
    pthread_mutex_lock(&lock);
    calibration_style = style; n_update_refused = 0; n_times = 0;
    for (int a = 0; a < 3; a++) cal_offset[a] = 0;
    sim_handle_init(&H, 10.0);
    t_origin = sim_clock();
    plugged = 1; initialized = 0; force_output = 0; clamping = 0; n_errors = 0; calibration = calibration_status;
    memset(cbs, 0, sizeof cbs);
    n_frames = n_calibrations = 0; max_commanded = max_applied = 0;
    for (int a = 0; a < 3; a++) frame_x[a] = frame_v[a] = 0;
    pthread_mutex_unlock(&lock);
}
void sim_set_hand(const double *p0, const double *amp, double freq, double k, double b) {
    pthread_mutex_lock(&lock);
    sim_handle_advance(&H, now());
    for (int a = 0; a < 3; a++) { H.p0[a] = p0[a]; H.amp[a] = amp[a]; }
    H.freq = freq; H.kh = k; H.bh = b;
    pthread_mutex_unlock(&lock);
}
void sim_place(const double *x) {
    pthread_mutex_lock(&lock);
    sim_handle_advance(&H, now());
    for (int a = 0; a < 3; a++) { H.x[a] = x[a]; H.v[a] = 0; frame_x[a] = x[a]; frame_v[a] = 0; }
    pthread_mutex_unlock(&lock);
}
void sim_unplug(void) { pthread_mutex_lock(&lock); plugged = 0; pthread_mutex_unlock(&lock); }
/* x(3) m, v(3) m/s, applied force(3) N */
void sim_state(double *out) {
    pthread_mutex_lock(&lock);
    for (int a = 0; a < 3; a++) { out[a] = H.x[a]; out[3 + a] = H.v[a]; out[6 + a] = H.f[a]; }
    pthread_mutex_unlock(&lock);
}
/* how many asynchronous callbacks ran since sim_reset */
long sim_callback_count(void) { pthread_mutex_lock(&lock); long n = n_times; pthread_mutex_unlock(&lock); return n; }
/* the durations (s) of the last n asynchronous callbacks, oldest first; returns how many */
int sim_callback_times(double *out, int n) {
    pthread_mutex_lock(&lock);
    long have = n_times < N_TIMES ? n_times : N_TIMES;
    if (n > have) n = (int)have;
    for (int k = 0; k < n; k++) out[k] = cb_times[(n_times - n + k) % N_TIMES];
    pthread_mutex_unlock(&lock);
    return n;
}
/* frames, calibrations, largest commanded and applied force norms, force output, clamping,
 * scheduler running, callbacks scheduled, device initialized, calibration updates refused */
void sim_counters(double *out) {
    pthread_mutex_lock(&lock);
    int n = 0;
    for (int k = 0; k < MAX_CB; k++) n += cbs[k].used;
    out[0] = n_frames; out[1] = n_calibrations; out[2] = max_commanded; out[3] = max_applied;
    out[4] = force_output; out[5] = clamping; out[6] = running; out[7] = n; out[8] = initialized;
    out[9] = n_update_refused;
    pthread_mutex_unlock(&lock);
}
