// rbgen host runtime: replays a World's step from an `rbgen export --world` directory.
//
// C++17 and the OpenCL C API, nothing else. `rbgen::Host` loads the export (schedule.json,
// the kernels, data/), checks that it was made for this device and driver, builds the
// programs, allocates the buffers and runs steps exactly as the Python World enqueues them:
// the same launches with the same arguments in the same order, the step report read
// without blocking, and on overflow the same redo (restore the bodies, rewind, grow,
// enqueue again). SCHEDULE.md (beside this file) describes the format it reads.
//
// Errors throw rbgen::Error whose message names the file, field or device at fault.
#pragma once

#ifndef CL_TARGET_OPENCL_VERSION
#define CL_TARGET_OPENCL_VERSION 120
#endif
#ifdef __APPLE__
#include <OpenCL/cl.h>
#else
#include <CL/cl.h>
#endif

#include <cstdint>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace rbgen {

// The schedule format this runtime reads (schedule.json's "version").
constexpr int kScheduleVersion = 1;

class Error : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

struct HostOptions {
    // Start these capacities at 2^rung instead of the export's (e.g. {"pairs", 0}: the
    // smallest, so that the first steps overflow, grow and redo).
    std::map<std::string, int> start_rungs;
    // A substring of "<platform> <device>" to choose among devices with the export's
    // fingerprint (default: the first one).
    std::string device;
    // Time every command with OpenCL profiling events (device_seconds); costs host time.
    bool profile = false;
};

// Seconds spent by the host in step() and in waiting for the device inside it.
struct HostTimes {
    double in_step = 0.0;   // wall time inside step() and finish()
    double waiting = 0.0;   // of which: blocked on the device (report reads, redos)
};

class Host {
public:
    explicit Host(const std::string& directory, const HostOptions& options = HostOptions());
    ~Host();
    Host(const Host&) = delete;
    Host& operator=(const Host&) = delete;

    // Enqueue one step (the export's dt). Checks the report of the step before the last
    // (its copy is long done), redoing from a step that overflowed.
    void step();
    // Check every step in flight (redoing as needed) and wait for the device.
    void finish();

    std::size_t body_count() const;
    // Body state after the steps so far (finishes first): N x 3 or N x 4 floats.
    std::vector<float> positions();
    std::vector<float> orientations();      // quaternions x, y, z, w
    std::vector<float> linear_velocities();
    std::vector<float> angular_velocities();
    std::vector<float> inverse_masses();     // 0 for static bodies

    long steps() const;             // steps taken (redos not counted twice)
    int overflows() const;          // redos after an overflow (each grew a capacity)
    std::map<std::string, long> capacities() const;
    std::string device_name() const;
    std::string plan() const;       // the plan's one-line description
    double dt() const;
    const HostTimes& times() const;
    // With HostOptions::profile: the device's time in the steps' commands (kernels, fills,
    // copies) since the last call, from their events (finishes first).
    double device_seconds();

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

// The fingerprint of an OpenCL device as rbgen computes it (rbgen.device.DeviceTraits):
// a slug of its name and a hash of its traits and driver version.
std::string device_fingerprint(cl_device_id device);

}  // namespace rbgen
