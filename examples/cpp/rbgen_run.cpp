// rbgen_run: load an `rbgen export --world` directory, run N steps, print ms/step and a
// sanity line; optionally dump the bodies' state.
//
//   rbgen_run DIR N [--warmup W] [--blocks B] [--capacity NAME=RUNG]... [--device SUBSTRING]
//                   [--profile] [--dump FILE] [--json]
//
// --warmup W    steps run before the timed ones (the first runs of every kernel)
// --blocks B    the timed steps are clocked in B blocks (default 10): ms/step is the median
//               block's, robust to a block that a neighbour on the machine slowed
// --profile     also the device's time per step, from profiling events on every command
//               (which cost host time: time the host without it)
// --capacity    start a capacity at 2^RUNG (e.g. pairs=0: the smallest, so that it must
//               grow and redo); the export's own value otherwise
// --dump FILE   after the steps, write four float32 arrays back to back: positions N x 3,
//               orientations N x 4 (x, y, z, w), linear and angular velocities N x 3 each
// --json        also print one line "result {...}" with the numbers
//
// ms/step: the timed steps are enqueued back to back and ended by one finish, clocked at
// the block boundaries (as rbgen.harness does): the device's time whenever the host keeps
// ahead of it. "host" is the time spent in step() less the time it waited for the device.
#include <algorithm>
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
    std::cerr << "usage: rbgen_run DIR N [--warmup W] [--blocks B] [--capacity NAME=RUNG]... "
                 "[--device SUBSTRING] [--profile] [--dump FILE] [--json]\n";
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
    long warmup = 0, blocks = 10;
    std::string dump;
    bool json = false;
    rbgen::HostOptions options;
    for (int i = 3; i < argc; ++i) {
        std::string arg = argv[i];
        if (arg == "--warmup" && i + 1 < argc) {
            warmup = parse_count(argv[++i], "--warmup");
        } else if (arg == "--blocks" && i + 1 < argc) {
            blocks = std::max(1L, parse_count(argv[++i], "--blocks"));
        } else if (arg == "--profile") {
            options.profile = true;
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
        if (options.profile) host.device_seconds();  // (not the warm-up's)
        blocks = std::min(blocks, std::max(1L, steps));
        std::vector<double> block_ms, block_host_ms;
        auto clock = [] { return std::chrono::steady_clock::now(); };
        auto t0 = clock();
        rbgen::HostTimes before = host.times();
        for (long b = 0; b < blocks; ++b) {
            long count = steps / blocks + (b == blocks - 1 ? steps % blocks : 0);
            auto start = clock();
            rbgen::HostTimes at = host.times();
            for (long s = 0; s < count; ++s) host.step();
            if (b == blocks - 1) host.finish();
            const rbgen::HostTimes& now = host.times();
            double seconds = std::chrono::duration<double>(clock() - start).count();
            double host_seconds = (now.in_step - at.in_step) - (now.waiting - at.waiting);
            if (count) {
                block_ms.push_back(1e3 * seconds / static_cast<double>(count));
                block_host_ms.push_back(1e3 * host_seconds / static_cast<double>(count));
            }
        }
        double wall = std::chrono::duration<double>(clock() - t0).count();
        const rbgen::HostTimes& after = host.times();
        double host_time = (after.in_step - before.in_step) - (after.waiting - before.waiting);
        double per = steps ? 1e3 / static_cast<double>(steps) : 0.0;
        auto median = [](std::vector<double> v) {
            if (v.empty()) return 0.0;
            std::sort(v.begin(), v.end());
            return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
        };
        double ms = median(block_ms), host_ms = median(block_host_ms);
        double low = block_ms.empty() ? 0.0 : *std::min_element(block_ms.begin(), block_ms.end());
        double high = block_ms.empty() ? 0.0 : *std::max_element(block_ms.begin(), block_ms.end());
        double device_ms = options.profile ? host.device_seconds() * per : -1.0;

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
        std::printf("%ld steps (+%ld warm-up) of %zu bodies at dt %.6g: %.3f ms/step "
                    "(blocks %.3f-%.3f, mean %.3f), host %.3f ms/step",
                    steps, warmup, n, host.dt(), ms, low, high, wall * per, host_ms);
        if (options.profile) std::printf(", device %.3f ms/step", device_ms);
        std::printf("; overflows %d, capacities%s\n", host.overflows(), capacities.c_str());
        std::printf("sanity: NaNs %zu, dynamic bodies %zu, mean y %.4f m, lowest y %.4f m, "
                    "max speed %.4f m/s\n", nans, dynamic, mean_y, dynamic ? lowest : 0.0,
                    fastest);
        if (json) {
            std::printf("result {\"steps\": %ld, \"warmup\": %ld, \"bodies\": %zu, "
                        "\"ms_per_step\": %.6f, \"ms_spread\": [%.6f, %.6f], "
                        "\"ms_mean\": %.6f, \"host_ms_per_step\": %.6f, "
                        "\"host_ms_mean\": %.6f, ", steps, warmup, n, ms, low, high, wall * per,
                        host_ms, host_time * per);
            if (options.profile) std::printf("\"device_ms_per_step\": %.6f, ", device_ms);
            else std::printf("\"device_ms_per_step\": null, ");
            std::printf("\"overflows\": %d, \"nans\": %zu}\n", host.overflows(), nans);
        }
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
