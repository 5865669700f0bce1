// arsurf_client.cpp - a C++ client of the arsurf haptic UDP bridge (protocol version 3).
//
// The same job as the Python reference client (python -m arsurf.haptics.client): read the
// session key file arsurf wrote, say HELLO and take the session id from the bridge's CHALLENGE
// (again when no valid FORCE came for --timeout: the bridge may have restarted), send one
// authenticated POSE of that session per servo tick (1 kHz by default),
// check every FORCE reply (sender, tag, sequence number, ack, finite values, force limit) and
// apply only those, zero force when none arrived for --timeout, RELEASE at the end, and a JSON
// summary on stdout. All protocol code is include/arsurf_bridge.h.
//
// It moves a simulated stylus; a CHAI3D or OpenHaptics program replaces the two functions marked
// DEVICE below (read_stylus, apply_force) with its device's calls. The bridge's frame is arsurf's
// (docs/bridge-protocol.rst: x right, y away from the operator, z up, metres, newtons; the force
// is the one to apply to the stylus), not the device's: for OpenHaptics (x right, y up, z towards
// the operator, millimetres), in the servo callback,
//   hdGetDoublev(HD_CURRENT_POSITION, p_mm); from_openhaptics(p_mm, pos);   // and the velocity alike
//   to_openhaptics(f, f_hd); hdSetDoublev(HD_CURRENT_FORCE, f_hd);
// for CHAI3D (x towards the operator, y right, z up, metres): pos = (y, -x, z), force (-Fy, Fx, Fz).
//
// Build (POSIX: Linux, macOS):
//   g++ -std=c++11 -O2 -ffp-contract=off -I../../include arsurf_client.cpp -o arsurf_client
// or with CMake (CMakeLists.txt beside this file). Run against `arsurf view --bridge-port 47474`:
//   ./arsurf_client --port 47474 --key-file /tmp/arsurf-bridge-xyz/bridge.key --duration 5
//
// The simulated stylus: at tick k (t = k / rate) it is at
//   x = radius cos(2 pi frequency t), y = radius sin(2 pi frequency t),
//   z = -press * s(t) with s rising 0 -> 1 over the first 30 % of --duration (s = (1 - cos(pi u)) / 2),
//       1 until 70 %, back to 0 by the end,
// in metres, with its exact velocity (so the server need not differentiate).
#include "arsurf_bridge.h"

#include <algorithm>
#include <arpa/inet.h>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <string>
#include <sys/socket.h>
#include <thread>
#include <unistd.h>
#include <vector>

namespace {

struct Options {
    std::string host = "127.0.0.1";
    int port = ARSURF_DEFAULT_PORT;
    std::string key_file;
    double rate = 1000.0;       // poses per second
    double duration = 5.0;      // s
    double radius = 0.02;       // m
    double frequency = 0.5;     // Hz
    double press = 0.0;         // m, how far the stylus goes down
    double max_force = 7.9;     // N, the device's limit
    double timeout = 0.1;       // s without a valid FORCE -> zero force
    double wait = 0.0;          // s to wait for the bridge's first reply before the path starts
    int local_port = 0;
    bool lockstep = false;      // wait for the reply to each pose before the next (tests, latency)
    std::string log;            // CSV of every tick
};

[[noreturn]] void usage_error(const std::string &msg) {
    std::fprintf(stderr, "arsurf_client: error: %s (see arsurf_client --help)\n", msg.c_str());
    std::exit(2);
}

const char *HELP =
    "usage: arsurf_client --key-file PATH [--host A] [--port P] [--rate HZ] [--duration S]\n"
    "                     [--radius M] [--frequency HZ] [--press M] [--max-force N] [--timeout S]\n"
    "                     [--wait S] [--local-port P] [--lockstep] [--log FILE] | --self-test\n"
    "Drive an arsurf UDP bridge (protocol 3) with a simulated stylus: a circle of --radius metres\n"
    "at --frequency Hz, pressed --press metres down in the middle of --duration seconds.\n"
    "--wait S: first wait up to S s for the bridge's first reply. --lockstep: wait for the\n"
    "reply to each pose before sending the next. --log FILE: CSV, one row per tick.\n"
    "--self-test: check SHA-256, HMAC-SHA256 and the protocol's test vector on this platform.\n";

double number(const char *flag, const char *text, double lo, double hi) {
    char *end = nullptr;
    errno = 0;
    double v = std::strtod(text, &end);
    if (errno != 0 || end == text || *end != '\0' || !std::isfinite(v) || v < lo || v > hi)
        usage_error(std::string("argument ") + flag + ": must be a number in [" + std::to_string(lo) + ", " +
                    std::to_string(hi) + "] (got '" + text + "')");
    return v;
}

Options parse(int argc, char **argv) {
    Options o;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        auto value = [&](void) -> const char * {
            if (i + 1 >= argc) usage_error("argument " + a + ": expected a value");
            return argv[++i];
        };
        if (a == "--help" || a == "-h") {
            std::fputs(HELP, stdout);
            std::exit(0);
        } else if (a == "--self-test") {
            int failed = arsurf_self_test();
            std::printf("{\"self_test\": \"%s\", \"failed_check\": %d}\n", failed ? "failed" : "ok", failed);
            std::exit(failed ? 1 : 0);
        } else if (a == "--host") o.host = value();
        else if (a == "--port") o.port = (int)number("--port", value(), 1, 65535);
        else if (a == "--key-file") o.key_file = value();
        else if (a == "--rate") o.rate = number("--rate", value(), 1.0, 20000.0);
        else if (a == "--duration") o.duration = number("--duration", value(), 0.0, 86400.0);
        else if (a == "--radius") o.radius = number("--radius", value(), 0.0, 1.0);
        else if (a == "--frequency") o.frequency = number("--frequency", value(), 0.0, 1000.0);
        else if (a == "--press") o.press = number("--press", value(), 0.0, 1.0);
        else if (a == "--max-force") o.max_force = number("--max-force", value(), 1e-9, 1e6);
        else if (a == "--timeout") o.timeout = number("--timeout", value(), 1e-4, 60.0);
        else if (a == "--wait") o.wait = number("--wait", value(), 0.0, 86400.0);
        else if (a == "--local-port") o.local_port = (int)number("--local-port", value(), 0, 65535);
        else if (a == "--lockstep") o.lockstep = true;
        else if (a == "--log") o.log = value();
        else usage_error("unknown argument '" + a + "'");
    }
    if (o.key_file.empty()) usage_error("give the session key with --key-file PATH (arsurf view prints it)");
    return o;
}

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

// ---- frames: OpenHaptics' HD frame (x right, y up, z towards the operator; mm) <-> the bridge's ----
// (x right, y away from the operator, z up; m). A rotation, so the power F.v is the same in both.
inline void from_openhaptics(const double hd_mm[3], double out_m[3]) {
    out_m[0] = 1e-3 * hd_mm[0];
    out_m[1] = -1e-3 * hd_mm[2];
    out_m[2] = 1e-3 * hd_mm[1];
}
inline void to_openhaptics(const double f[3], double hd[3]) {
    hd[0] = f[0];
    hd[1] = f[2];
    hd[2] = -f[1];
}
// the two conversions: a press down (bridge -z) is HD -y, and a force back up (bridge +z) is HD +y
inline bool frames_ok() {
    const double down_hd[3] = {0.0, -2.0, 0.0}, up[3] = {0.0, 0.0, 1.5};
    double p[3], f[3];
    from_openhaptics(down_hd, p);
    to_openhaptics(up, f);
    return p[0] == 0.0 && p[1] == 0.0 && p[2] == -2e-3 && f[0] == 0.0 && f[1] == 1.5 && f[2] == 0.0;
}

// ---- DEVICE: the simulated stylus (replace with the device's position and velocity, in m, m/s) ----
void read_stylus(const Options &o, long k, double pos[3], double vel[3]) {
    const double pi = 3.14159265358979323846;
    double t = k / o.rate, w = 2.0 * pi * o.frequency, T = o.duration;
    pos[0] = o.radius * std::cos(w * t);
    pos[1] = o.radius * std::sin(w * t);
    vel[0] = -o.radius * w * std::sin(w * t);
    vel[1] = o.radius * w * std::cos(w * t);
    double s = 0.0, ds = 0.0;  // the press profile and its time derivative
    if (T > 0.0 && o.press > 0.0) {
        if (t < 0.3 * T) {
            double u = t / (0.3 * T);
            s = 0.5 * (1.0 - std::cos(pi * u));
            ds = 0.5 * pi * std::sin(pi * u) / (0.3 * T);
        } else if (t < 0.7 * T) {
            s = 1.0;
        } else if (t < T) {
            double u = (t - 0.7 * T) / (0.3 * T);
            s = 0.5 * (1.0 + std::cos(pi * u));
            ds = -0.5 * pi * std::sin(pi * u) / (0.3 * T);
        }
    }
    pos[2] = -o.press * s;
    vel[2] = -o.press * ds;
}

// ---- DEVICE: the force to put on the handle, N (a real client calls its device here) ----
double g_max_applied = 0.0;
void apply_force(const double f[3]) {
    g_max_applied = std::max(g_max_applied, std::sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]));
}

struct Bridge {
    int sock = -1;
    sockaddr_in server{};
    arsurf_client c{};
    arsurf_force last{};        // the last accepted FORCE
    bool have_force = false;
    Clock::time_point last_rx;  // when it arrived
    Clock::time_point t0;       // the client clock's origin (timestamps in POSE packets)
    double last_t = -1.0;       // the last POSE timestamp (strictly increasing)
    unsigned long sent = 0, hellos = 0, send_errors = 0, receive_errors = 0;
    Clock::time_point last_hello;
    bool hello_sent = false;
    std::vector<double> rtts;

    double stamp() {  // a strictly increasing client time, s
        double t = seconds_since(t0);
        if (!(t > last_t)) t = std::nextafter(last_t, 1e300);
        last_t = t;
        return t;
    }

    void send_hello() {
        uint8_t pkt[ARSURF_HELLO_SIZE];
        arsurf_client_hello(&c, stamp(), pkt);
        last_hello = Clock::now();
        hello_sent = true;
        ++hellos;
        if (sendto(sock, pkt, sizeof pkt, 0, (const sockaddr *)&server, sizeof server) != (ssize_t)sizeof pkt)
            ++send_errors;
    }

    // One POSE of the session (its sequence number), or 0: no session yet, a HELLO was sent instead.
    // With a session but no valid FORCE for `timeout`, also a HELLO, once per `timeout`.
    uint64_t send_pose(const double pos[3], const double vel[3], double timeout) {
        if (!c.have_session ||
            (!fresh(timeout) && (!hello_sent || std::chrono::duration<double>(Clock::now() - last_hello).count() > timeout))) {
            send_hello();
            if (!c.have_session) return 0;
        }
        arsurf_pose p = arsurf_pose_at(stamp(), pos, vel);
        uint8_t pkt[ARSURF_POSE_SIZE];
        uint64_t seq = arsurf_client_pose(&c, &p, pkt);
        if (sendto(sock, pkt, sizeof pkt, 0, (const sockaddr *)&server, sizeof server) == (ssize_t)sizeof pkt)
            ++sent;
        else
            ++send_errors;  // the bridge not there yet (ICMP unreachable), buffer full: keep going
        return seq;
    }

    void release() {
        uint8_t pkt[ARSURF_RELEASE_SIZE];
        if (arsurf_client_release(&c, stamp(), pkt) == 0) return;  // no session: nothing to release
        if (sendto(sock, pkt, sizeof pkt, 0, (const sockaddr *)&server, sizeof server) != (ssize_t)sizeof pkt)
            ++send_errors;
    }

    // Read every datagram waiting (or, with wait_ms > 0, the first one to arrive within it);
    // returns the number of FORCE packets accepted.
    int drain(int wait_ms) {
        int accepted = 0;
        for (;;) {
            pollfd pfd{sock, POLLIN, 0};
            int r = poll(&pfd, 1, wait_ms);
            if (r <= 0) return accepted;
            wait_ms = 0;
            uint8_t buf[2048];
            sockaddr_in from{};
            socklen_t fl = sizeof from;
            ssize_t n = recvfrom(sock, buf, sizeof buf, 0, (sockaddr *)&from, &fl);
            if (n < 0) {
                ++receive_errors;  // e.g. ICMP port unreachable while the bridge starts
                continue;
            }
            int from_server = fl >= (socklen_t)sizeof from && from.sin_family == AF_INET &&
                              from.sin_addr.s_addr == server.sin_addr.s_addr && from.sin_port == server.sin_port;
            arsurf_force f;
            if (arsurf_client_check(&c, buf, (size_t)n, from_server, &f) != ARSURF_OK) continue;
            last = f;
            have_force = true;
            last_rx = Clock::now();
            if (std::isfinite(f.echo)) rtts.push_back(seconds_since(t0) - f.echo);
            ++accepted;
        }
    }

    // The force to apply now: the last accepted one, or zero if it is older than `timeout`.
    bool fresh(double timeout) const {
        return have_force && std::chrono::duration<double>(Clock::now() - last_rx).count() <= timeout;
    }
};

void open_socket(Bridge &b, const Options &o) {
    addrinfo hints{}, *res = nullptr;
    hints.ai_family = AF_INET;
    hints.ai_socktype = SOCK_DGRAM;
    int rc = getaddrinfo(o.host.c_str(), std::to_string(o.port).c_str(), &hints, &res);
    if (rc != 0 || res == nullptr) usage_error("cannot resolve --host " + o.host + ": " + gai_strerror(rc));
    std::memcpy(&b.server, res->ai_addr, sizeof b.server);
    freeaddrinfo(res);
    b.sock = socket(AF_INET, SOCK_DGRAM, 0);
    if (b.sock < 0) usage_error(std::string("cannot open a UDP socket: ") + std::strerror(errno));
    sockaddr_in local{};
    local.sin_family = AF_INET;
    local.sin_port = htons((uint16_t)o.local_port);
    bool loopback = (ntohl(b.server.sin_addr.s_addr) >> 24) == 127;
    local.sin_addr.s_addr = loopback ? htonl(INADDR_LOOPBACK) : htonl(INADDR_ANY);
    if (bind(b.sock, (const sockaddr *)&local, sizeof local) != 0)
        usage_error("cannot bind local UDP port " + std::to_string(o.local_port) + ": " + std::strerror(errno));
}

double percentile(std::vector<double> v, double q) {
    if (v.empty()) return NAN;
    std::sort(v.begin(), v.end());
    size_t i = std::min(v.size() - 1, (size_t)(q * (double)v.size()));
    return v[i];
}

void json_number(FILE *out, double x) {
    if (std::isfinite(x)) std::fprintf(out, "%.17g", x);
    else std::fputs("null", out);
}

}  // namespace

int main(int argc, char **argv) {
    Options o = parse(argc, argv);
    if (!frames_ok()) {  // the frame conversions a device client needs (docs/bridge-protocol.rst)
        std::fprintf(stderr, "arsurf_client: the OpenHaptics frame conversion is wrong\n");
        return 1;
    }
    if (arsurf_self_test() != 0) {  // a compiler or platform that gets the bytes wrong never talks to a device
        std::fprintf(stderr, "arsurf_client: error: the protocol self-test failed (check %d) on this platform\n",
                     arsurf_self_test());
        return 1;
    }
    uint8_t key[ARSURF_KEY_MAX];
    size_t keylen = 0;
    char err[512];
    if (arsurf_read_key_file(o.key_file.c_str(), key, &keylen, err, sizeof err) != 0) usage_error(err);

    Bridge b;
    open_socket(b, o);
    uint64_t wall_us = (uint64_t)std::chrono::duration_cast<std::chrono::microseconds>(
                           std::chrono::system_clock::now().time_since_epoch()).count();
    if (arsurf_client_init(&b.c, key, keylen, wall_us, o.max_force) != 0) usage_error("bad key or --max-force");
    std::memset(key, 0, sizeof key);
    b.t0 = Clock::now();

    FILE *log = nullptr;
    if (!o.log.empty()) {
        log = std::fopen(o.log.c_str(), "w");
        if (!log) usage_error("cannot write --log " + o.log + ": " + std::strerror(errno));
        std::fputs("tick,seq,t_s,x_m,y_m,z_m,vx_m_per_s,vy_m_per_s,vz_m_per_s,fx_N,fy_N,fz_N,ack\n", log);
    }

    double pos[3], vel[3];
    // 1. wait for the bridge: the first pose every 10 ms until a valid FORCE comes back
    if (o.wait > 0.0) {
        read_stylus(o, 0, pos, vel);
        auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(o.wait));
        while (!b.have_force) {
            if (Clock::now() > deadline) {
                std::fprintf(stderr, "arsurf_client: error: no valid reply from the bridge at %s:%d within %g s "
                             "(%lu datagrams dropped: wrong key? see the counters in the JSON)\n",
                             o.host.c_str(), o.port, o.wait, arsurf_client_dropped(&b.c));
                b.release();
                close(b.sock);
                return 3;
            }
            b.send_pose(pos, vel, o.timeout);
            b.drain(10);
        }
    }

    // 2. the path: one pose per tick on absolute deadlines (or in lockstep with the replies)
    const long n = (long)std::llround(o.duration * o.rate);
    const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / o.rate));
    unsigned long zeroed = 0, late = 0, lockstep_timeouts = 0;
    auto start = Clock::now();
    for (long k = 0; k < n; ++k) {
        read_stylus(o, k, pos, vel);
        uint64_t seq = b.send_pose(pos, vel, o.timeout);
        if (o.lockstep) {  // the reply to this pose (or, for a HELLO, the CHALLENGE)
            auto deadline = Clock::now() + std::chrono::seconds(2);
            auto answered = [&]() { return seq == 0 ? b.c.have_session != 0 : (b.have_force && b.last.ack >= seq); };
            while (!answered() && Clock::now() < deadline) b.drain(5);
            if (!answered()) ++lockstep_timeouts;
        } else {
            b.drain(0);
        }
        double f[3] = {0.0, 0.0, 0.0};
        if (b.fresh(o.timeout)) std::memcpy(f, b.last.force, sizeof f);
        else ++zeroed;
        apply_force(f);
        if (log)
            std::fprintf(log, "%ld,%llu,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%llu\n", k,
                         (unsigned long long)seq, b.last_t, pos[0], pos[1], pos[2], vel[0], vel[1], vel[2], f[0],
                         f[1], f[2], (unsigned long long)(b.have_force ? b.last.ack : 0));
        if (!o.lockstep) {
            auto deadline = start + (k + 1) * period;
            if (Clock::now() > deadline + period) ++late;
            std::this_thread::sleep_until(deadline);
        }
    }
    // 3. the last replies (50 ms of them), then RELEASE: the bridge unpins this client
    for (auto end = Clock::now() + std::chrono::milliseconds(50); Clock::now() < end;) b.drain(1);
    double zero[3] = {0.0, 0.0, 0.0};
    apply_force(zero);
    b.release();
    if (log) std::fclose(log);
    close(b.sock);

    std::printf("{\n  \"sent\": %lu,\n  \"hellos\": %lu,\n  \"ticks\": %ld,\n  \"send_errors\": %lu,\n"
                "  \"accepted_replies\": %lu,\n", b.sent, b.hellos, n, b.send_errors, b.c.counts[ARSURF_OK]);
    std::printf("  \"replies_with_rtt\": %zu,\n  \"invalid_replies\": %lu,\n  \"dropped_replies\": {", b.rtts.size(),
                arsurf_client_dropped(&b.c));
    bool first = true;
    for (int s = 1; s < ARSURF_CHALLENGE; ++s)
        if (b.c.counts[s]) {
            std::printf("%s\"%s\": %lu", first ? "" : ", ", arsurf_status_name((arsurf_status)s), b.c.counts[s]);
            first = false;
        }
    std::printf("},\n  \"ticks_with_zero_force_for_timeout\": %lu,\n  \"late_ticks\": %lu,\n", zeroed, late);
    std::printf("  \"lockstep_timeouts\": %lu,\n  \"rtt_median_s\": ", lockstep_timeouts);
    json_number(stdout, percentile(b.rtts, 0.5));
    std::printf(",\n  \"rtt_p99_s\": ");
    json_number(stdout, percentile(b.rtts, 0.99));
    std::printf(",\n  \"max_force_N\": ");
    json_number(stdout, g_max_applied);
    std::printf(",\n  \"released\": true\n}\n");
    return b.c.counts[ARSURF_OK] > 0 ? 0 : 3;
}
