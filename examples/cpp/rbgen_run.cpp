// rbgen_run: load an `rbgen export --world` directory, run N steps, print ms/step and a
// sanity line; optionally dump the bodies' state.
//
//   rbgen_run DIR N [--warmup W] [--capacity NAME=RUNG]... [--device SUBSTRING]
//                   [--dump FILE] [--json]
//
// --warmup W    steps run before the timed ones (the first runs of every kernel)
// --capacity    start a capacity at 2^RUNG (e.g. pairs=0: the smallest, so that it must
//               grow and redo); the export's own value otherwise
// --dump FILE   after the steps, write four float32 arrays back to back: positions N x 3,
//               orientations N x 4 (x, y, z, w), linear and angular velocities N x 3 each
// --json        also print one line "result {...}" with the numbers
//
// ms/step is the wall time of the timed steps, enqueued back to back and ended by one
// finish, over their number: the device's time whenever the host keeps ahead of it.
// "host" is the time spent in step() less the time it waited for the device.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

#include "rbgen_host.hpp"

namespace {

int usage() {
    std::cerr << "usage: rbgen_run DIR N [--warmup W] [--capacity NAME=RUNG]... "
                 "[--device SUBSTRING] [--dump FILE] [--json]\n";
    return 2;
}

long parse_count(const char* text, const char* what) {
    char* end = nullptr;
    long value = std::strtol(text, &end, 10);
    if (!end || *end || value < 0) {
        std::cerr << "rbgen_run: " << what << " must be a non-negative integer, got '" << text
                  << "'\n";
        std::exit(2);
    }
    return value;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 3) return usage();
    std::string dir = argv[1];
    long steps = parse_count(argv[2], "N");
    long warmup = 0;
    std::string dump;
    bool json = false;
    rbgen::HostOptions options;
    for (int i = 3; i < argc; ++i) {
        std::string arg = argv[i];
        if (arg == "--warmup" && i + 1 < argc) {
            warmup = parse_count(argv[++i], "--warmup");
        } else if (arg == "--capacity" && i + 1 < argc) {
            std::string item = argv[++i];
            std::size_t eq = item.find('=');
            if (eq == std::string::npos) return usage();
            options.start_rungs[item.substr(0, eq)] =
                static_cast<int>(parse_count(item.c_str() + eq + 1, "--capacity's rung"));
        } else if (arg == "--device" && i + 1 < argc) {
            options.device = argv[++i];
        } else if (arg == "--dump" && i + 1 < argc) {
            dump = argv[++i];
        } else if (arg == "--json") {
            json = true;
        } else {
            return usage();
        }
    }
    try {
        rbgen::Host host(dir, options);
        std::cout << "device: " << host.device_name() << "\nplan: " << host.plan() << "\n";
        for (long s = 0; s < warmup; ++s) host.step();
        host.finish();
        rbgen::HostTimes before = host.times();
        auto t0 = std::chrono::steady_clock::now();
        for (long s = 0; s < steps; ++s) host.step();
        host.finish();
        double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        const rbgen::HostTimes& after = host.times();
        double host_time = (after.in_step - before.in_step) - (after.waiting - before.waiting);
        double per = steps ? 1e3 / static_cast<double>(steps) : 0.0;

        std::vector<float> p = host.positions(), lv = host.linear_velocities();
        std::vector<float> inv_mass = host.inverse_masses();
        std::size_t n = host.body_count(), dynamic = 0, nans = 0;
        double mean_y = 0.0, lowest = INFINITY, fastest = 0.0;
        for (std::size_t i = 0; i < n; ++i) {
            bool bad = false;
            for (int k = 0; k < 3; ++k) bad = bad || !std::isfinite(p[3 * i + k]);
            nans += bad;
            if (inv_mass[i] == 0.0f || bad) continue;
            ++dynamic;
            mean_y += p[3 * i + 1];
            lowest = std::min(lowest, double(p[3 * i + 1]));
            double v = std::sqrt(lv[3 * i] * lv[3 * i] + lv[3 * i + 1] * lv[3 * i + 1] +
                                 lv[3 * i + 2] * lv[3 * i + 2]);
            fastest = std::max(fastest, v);
        }
        if (dynamic) mean_y /= static_cast<double>(dynamic);
        std::string capacities;
        for (const auto& c : host.capacities())
            if (c.first.find('.') == std::string::npos)
                capacities += " " + c.first + "=" + std::to_string(c.second);
        std::printf("%ld steps (+%ld warm-up) of %zu bodies at dt %.6g: %.3f ms/step, host "
                    "%.3f ms/step; overflows %d, capacities%s\n",
                    steps, warmup, n, host.dt(), wall * per, host_time * per, host.overflows(),
                    capacities.c_str());
        std::printf("sanity: NaNs %zu, dynamic bodies %zu, mean y %.4f m, lowest y %.4f m, "
                    "max speed %.4f m/s\n", nans, dynamic, mean_y, dynamic ? lowest : 0.0,
                    fastest);
        if (json)
            std::printf("result {\"steps\": %ld, \"warmup\": %ld, \"bodies\": %zu, "
                        "\"ms_per_step\": %.6f, \"host_ms_per_step\": %.6f, \"overflows\": %d, "
                        "\"nans\": %zu}\n", steps, warmup, n, wall * per, host_time * per,
                        host.overflows(), nans);
        if (!dump.empty()) {
            std::ofstream out(dump, std::ios::binary);
            if (!out) throw rbgen::Error("cannot write " + dump);
            for (const std::vector<float>& a : {p, host.orientations(), lv,
                                                host.angular_velocities()})
                out.write(reinterpret_cast<const char*>(a.data()),
                          static_cast<std::streamsize>(a.size() * sizeof(float)));
            if (!out) throw rbgen::Error("cannot write " + dump);
        }
        return nans ? 1 : 0;
    } catch (const rbgen::Error& e) {
        std::cerr << "rbgen_run: error: " << e.what() << "\n";
        return 1;
    }
}
