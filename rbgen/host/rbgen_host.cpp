// rbgen host runtime (see rbgen_host.hpp and SCHEDULE.md).
#include "rbgen_host.hpp"

#include <algorithm>
#include <array>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <deque>
#include <fstream>
#include <sstream>
#include <utility>

namespace rbgen {
namespace {

// ---------------------------------------------------------------------------- SHA-256

class Sha256 {
public:
    Sha256() { reset(); }
    void update(const uint8_t* data, std::size_t size) {
        for (std::size_t i = 0; i < size; ++i) {
            block_[used_++] = data[i];
            if (used_ == 64) {
                compress();
                used_ = 0;
            }
        }
        length_ += size;
    }
    std::string hex() {
        uint64_t bits = length_ * 8;
        uint8_t one = 0x80, zero = 0;
        update(&one, 1);
        while (used_ != 56) update(&zero, 1);
        for (int i = 7; i >= 0; --i) {
            uint8_t b = static_cast<uint8_t>(bits >> (8 * i));
            update(&b, 1);
        }
        std::string out;
        char buf[9];
        for (uint32_t h : h_) {
            std::snprintf(buf, sizeof buf, "%08x", h);
            out += buf;
        }
        return out;
    }

private:
    static uint32_t rotr(uint32_t x, int n) { return (x >> n) | (x << (32 - n)); }
    void reset() {
        h_ = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a,
              0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
        used_ = 0;
        length_ = 0;
    }
    void compress() {
        static const uint32_t k[64] = {
            0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4,
            0xab1c5ed5, 0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe,
            0x9bdc06a7, 0xc19bf174, 0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f,
            0x4a7484aa, 0x5cb0a9dc, 0x76f988da, 0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7,
            0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967, 0x27b70a85, 0x2e1b2138, 0x4d2c6dfc,
            0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85, 0xa2bfe8a1, 0xa81a664b,
            0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070, 0x19a4c116,
            0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
            0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7,
            0xc67178f2};
        uint32_t w[64];
        for (int i = 0; i < 16; ++i)
            w[i] = (uint32_t(block_[4 * i]) << 24) | (uint32_t(block_[4 * i + 1]) << 16) |
                   (uint32_t(block_[4 * i + 2]) << 8) | uint32_t(block_[4 * i + 3]);
        for (int i = 16; i < 64; ++i) {
            uint32_t s0 = rotr(w[i - 15], 7) ^ rotr(w[i - 15], 18) ^ (w[i - 15] >> 3);
            uint32_t s1 = rotr(w[i - 2], 17) ^ rotr(w[i - 2], 19) ^ (w[i - 2] >> 10);
            w[i] = w[i - 16] + s0 + w[i - 7] + s1;
        }
        uint32_t a = h_[0], b = h_[1], c = h_[2], d = h_[3], e = h_[4], f = h_[5], g = h_[6],
                 h = h_[7];
        for (int i = 0; i < 64; ++i) {
            uint32_t t1 = h + (rotr(e, 6) ^ rotr(e, 11) ^ rotr(e, 25)) + ((e & f) ^ (~e & g)) +
                          k[i] + w[i];
            uint32_t t2 = (rotr(a, 2) ^ rotr(a, 13) ^ rotr(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
            h = g;
            g = f;
            f = e;
            e = d + t1;
            d = c;
            c = b;
            b = a;
            a = t1 + t2;
        }
        h_[0] += a; h_[1] += b; h_[2] += c; h_[3] += d;
        h_[4] += e; h_[5] += f; h_[6] += g; h_[7] += h;
    }
    std::array<uint32_t, 8> h_{};
    uint8_t block_[64]{};
    std::size_t used_ = 0;
    uint64_t length_ = 0;
};

std::string sha256_hex(const std::string& data) {
    Sha256 s;
    s.update(reinterpret_cast<const uint8_t*>(data.data()), data.size());
    return s.hex();
}

// ---------------------------------------------------------------------------- JSON

// A parsed JSON value; `where` is its path in the file, for messages.
struct Json {
    enum class Type { Null, Bool, Number, String, Array, Object } type = Type::Null;
    bool boolean = false;
    double number = 0.0;
    std::string text;  // a string, or a number's digits
    std::vector<Json> items;
    std::vector<std::pair<std::string, Json>> fields;
    std::string where;

    bool is_null() const { return type == Type::Null; }
    bool is_string() const { return type == Type::String; }
    bool is_object() const { return type == Type::Object; }
    [[noreturn]] void fail(const std::string& what) const;
    const Json* find(const std::string& key) const {
        for (const auto& f : fields)
            if (f.first == key) return &f.second;
        return nullptr;
    }
    const Json& operator[](const std::string& key) const {
        if (type != Type::Object) fail("is not an object");
        const Json* found = find(key);
        if (!found) fail("has no field '" + key + "'");
        return *found;
    }
    const Json& operator[](std::size_t index) const {
        if (type != Type::Array) fail("is not an array");
        if (index >= items.size()) fail("has no element " + std::to_string(index));
        return items[index];
    }
    const std::vector<Json>& array() const {
        if (type != Type::Array) fail("is not an array");
        return items;
    }
    const std::string& str() const {
        if (type != Type::String) fail("is not a string");
        return text;
    }
    int64_t integer() const {
        if (type != Type::Number || text.find_first_of(".eE") != std::string::npos)
            fail("is not an integer");
        return std::stoll(text);
    }
    double real() const {
        if (type != Type::Number) fail("is not a number");
        return number;
    }
    bool flag() const {
        if (type != Type::Bool) fail("is not true or false");
        return boolean;
    }
};

std::string g_json_file;  // (the file being read, for messages; one parse at a time)

void Json::fail(const std::string& what) const {
    throw Error(g_json_file + ": field " + (where.empty() ? "(top)" : where) + " " + what);
}

class JsonParser {
public:
    JsonParser(const std::string& text, const std::string& file) : s_(text), file_(file) {}
    Json parse() {
        Json value = parse_value("");
        skip();
        if (i_ != s_.size()) error("unexpected text after the document");
        return value;
    }

private:
    [[noreturn]] void error(const std::string& what) {
        throw Error(file_ + ": invalid JSON at byte " + std::to_string(i_) + ": " + what +
                    " (a corrupted or truncated file? export it again)");
    }
    void skip() {
        while (i_ < s_.size() && (s_[i_] == ' ' || s_[i_] == '\n' || s_[i_] == '\r' ||
                                  s_[i_] == '\t'))
            ++i_;
    }
    Json parse_value(const std::string& where) {
        skip();
        if (i_ >= s_.size()) error("unexpected end");
        Json v;
        v.where = where;
        char c = s_[i_];
        if (c == '{') {
            v.type = Json::Type::Object;
            ++i_;
            skip();
            if (i_ < s_.size() && s_[i_] == '}') { ++i_; return v; }
            while (true) {
                skip();
                std::string key = parse_string();
                skip();
                if (i_ >= s_.size() || s_[i_] != ':') error("expected ':'");
                ++i_;
                std::string path = where.empty() ? key : where + "." + key;
                v.fields.emplace_back(key, parse_value(path));
                skip();
                if (i_ < s_.size() && s_[i_] == ',') { ++i_; continue; }
                if (i_ < s_.size() && s_[i_] == '}') { ++i_; return v; }
                error("expected ',' or '}'");
            }
        }
        if (c == '[') {
            v.type = Json::Type::Array;
            ++i_;
            skip();
            if (i_ < s_.size() && s_[i_] == ']') { ++i_; return v; }
            while (true) {
                v.items.push_back(parse_value(where + "[" + std::to_string(v.items.size()) + "]"));
                skip();
                if (i_ < s_.size() && s_[i_] == ',') { ++i_; continue; }
                if (i_ < s_.size() && s_[i_] == ']') { ++i_; return v; }
                error("expected ',' or ']'");
            }
        }
        if (c == '"') {
            v.type = Json::Type::String;
            v.text = parse_string();
            return v;
        }
        if (s_.compare(i_, 4, "true") == 0) { i_ += 4; v.type = Json::Type::Bool; v.boolean = true; return v; }
        if (s_.compare(i_, 5, "false") == 0) { i_ += 5; v.type = Json::Type::Bool; return v; }
        if (s_.compare(i_, 4, "null") == 0) { i_ += 4; return v; }
        std::size_t start = i_;
        while (i_ < s_.size() && (std::isdigit(static_cast<unsigned char>(s_[i_])) ||
                                  s_[i_] == '-' || s_[i_] == '+' || s_[i_] == '.' ||
                                  s_[i_] == 'e' || s_[i_] == 'E'))
            ++i_;
        if (start == i_) error("unexpected character");
        v.type = Json::Type::Number;
        v.text = s_.substr(start, i_ - start);
        try {
            v.number = std::stod(v.text);
        } catch (const std::exception&) {
            error("bad number '" + v.text + "'");
        }
        return v;
    }
    std::string parse_string() {
        if (i_ >= s_.size() || s_[i_] != '"') error("expected a string");
        ++i_;
        std::string out;
        while (i_ < s_.size() && s_[i_] != '"') {
            char c = s_[i_++];
            if (c != '\\') { out += c; continue; }
            if (i_ >= s_.size()) error("unterminated escape");
            char e = s_[i_++];
            switch (e) {
                case 'n': out += '\n'; break;
                case 't': out += '\t'; break;
                case 'r': out += '\r'; break;
                case 'b': out += '\b'; break;
                case 'f': out += '\f'; break;
                case 'u': {
                    if (i_ + 4 > s_.size()) error("bad \\u escape");
                    unsigned code = std::stoul(s_.substr(i_, 4), nullptr, 16);
                    i_ += 4;
                    if (code < 0x80) out += static_cast<char>(code);
                    else if (code < 0x800) {
                        out += static_cast<char>(0xC0 | (code >> 6));
                        out += static_cast<char>(0x80 | (code & 0x3F));
                    } else {
                        out += static_cast<char>(0xE0 | (code >> 12));
                        out += static_cast<char>(0x80 | ((code >> 6) & 0x3F));
                        out += static_cast<char>(0x80 | (code & 0x3F));
                    }
                    break;
                }
                default: out += e;
            }
        }
        if (i_ >= s_.size()) error("unterminated string");
        ++i_;
        return out;
    }
    const std::string& s_;
    std::string file_;
    std::size_t i_ = 0;
};

// ---------------------------------------------------------------------------- files

std::string read_file(const std::string& path, const char* what) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Error("cannot open " + path + " (" + what + "): missing from the export?");
    std::ostringstream out;
    out << in.rdbuf();
    return out.str();
}

std::vector<uint8_t> from_hex(const std::string& hex, const Json& where) {
    if (hex.size() % 2) where.fail("is not a hex string");
    std::vector<uint8_t> out(hex.size() / 2);
    for (std::size_t i = 0; i < out.size(); ++i) {
        auto nibble = [&](char c) -> int {
            if (c >= '0' && c <= '9') return c - '0';
            if (c >= 'a' && c <= 'f') return c - 'a' + 10;
            if (c >= 'A' && c <= 'F') return c - 'A' + 10;
            where.fail("is not a hex string");
        };
        out[i] = static_cast<uint8_t>(nibble(hex[2 * i]) * 16 + nibble(hex[2 * i + 1]));
    }
    return out;
}

// ---------------------------------------------------------------------------- OpenCL

const char* cl_error_name(cl_int code) {
    switch (code) {
        case CL_DEVICE_NOT_FOUND: return "CL_DEVICE_NOT_FOUND";
        case CL_MEM_OBJECT_ALLOCATION_FAILURE: return "CL_MEM_OBJECT_ALLOCATION_FAILURE";
        case CL_OUT_OF_RESOURCES: return "CL_OUT_OF_RESOURCES";
        case CL_OUT_OF_HOST_MEMORY: return "CL_OUT_OF_HOST_MEMORY";
        case CL_BUILD_PROGRAM_FAILURE: return "CL_BUILD_PROGRAM_FAILURE";
        case CL_INVALID_VALUE: return "CL_INVALID_VALUE";
        case CL_INVALID_BUFFER_SIZE: return "CL_INVALID_BUFFER_SIZE";
        case CL_INVALID_KERNEL_NAME: return "CL_INVALID_KERNEL_NAME";
        case CL_INVALID_ARG_INDEX: return "CL_INVALID_ARG_INDEX";
        case CL_INVALID_ARG_VALUE: return "CL_INVALID_ARG_VALUE";
        case CL_INVALID_ARG_SIZE: return "CL_INVALID_ARG_SIZE";
        case CL_INVALID_KERNEL_ARGS: return "CL_INVALID_KERNEL_ARGS";
        case CL_INVALID_WORK_GROUP_SIZE: return "CL_INVALID_WORK_GROUP_SIZE";
        case CL_INVALID_GLOBAL_WORK_SIZE: return "CL_INVALID_GLOBAL_WORK_SIZE";
        case CL_INVALID_MEM_OBJECT: return "CL_INVALID_MEM_OBJECT";
        case CL_INVALID_BUILD_OPTIONS: return "CL_INVALID_BUILD_OPTIONS";
        case CL_MISALIGNED_SUB_BUFFER_OFFSET: return "CL_MISALIGNED_SUB_BUFFER_OFFSET";
        default: return "an OpenCL error";
    }
}

void check(cl_int code, const std::string& what) {
    if (code != CL_SUCCESS)
        throw Error(what + " failed: " + cl_error_name(code) + " (" + std::to_string(code) + ")");
}

std::string device_string(cl_device_id device, cl_device_info what) {
    std::size_t size = 0;
    check(clGetDeviceInfo(device, what, 0, nullptr, &size), "clGetDeviceInfo");
    std::string out(size, '\0');
    check(clGetDeviceInfo(device, what, size, &out[0], nullptr), "clGetDeviceInfo");
    return out;
}

std::string platform_string(cl_platform_id platform, cl_platform_info what) {
    std::size_t size = 0;
    check(clGetPlatformInfo(platform, what, 0, nullptr, &size), "clGetPlatformInfo");
    std::string out(size, '\0');
    check(clGetPlatformInfo(platform, what, size, &out[0], nullptr), "clGetPlatformInfo");
    return out;
}

// Python's str.strip() (the OpenCL strings also end in a NUL).
std::string strip(std::string s) {
    const char* space = " \t\n\r\v\f";
    s.erase(std::find(s.begin(), s.end(), '\0'), s.end());
    std::size_t a = s.find_first_not_of(space);
    if (a == std::string::npos) return "";
    std::size_t b = s.find_last_not_of(space);
    return s.substr(a, b - a + 1);
}

template <typename T>
T device_value(cl_device_id device, cl_device_info what) {
    T value{};
    check(clGetDeviceInfo(device, what, sizeof value, &value, nullptr), "clGetDeviceInfo");
    return value;
}

std::string lower(std::string s) {
    for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return s;
}

struct DeviceTraits {
    std::string platform_name, device_name, vendor, driver_version, opencl_version;
    bool is_gpu = false;
    cl_uint compute_units = 0;
    int wavefront = 1;
    cl_ulong local_mem_size = 0;
    std::size_t max_work_group_size = 0;

    std::string fingerprint() const {
        std::string text = platform_name + "|" + device_name + "|" + vendor + "|" +
                           (is_gpu ? "True" : "False") + "|" + std::to_string(compute_units) +
                           "|" + std::to_string(wavefront) + "|" +
                           std::to_string(local_mem_size) + "|" +
                           std::to_string(max_work_group_size) + "|" + driver_version + "|" +
                           opencl_version;
        std::string digest = sha256_hex(text).substr(0, 12);
        std::string slug;
        for (char c : lower(device_name))
            slug += std::isalnum(static_cast<unsigned char>(c)) ? c : '-';
        std::string joined;
        std::stringstream parts(slug);
        std::string part;
        while (std::getline(parts, part, '-')) {
            if (part.empty()) continue;
            if (!joined.empty()) joined += '-';
            joined += part;
        }
        return joined.substr(0, 40) + "-" + digest;
    }
};

DeviceTraits traits_of(cl_device_id device) {
    DeviceTraits t;
    cl_platform_id platform = device_value<cl_platform_id>(device, CL_DEVICE_PLATFORM);
    t.platform_name = strip(platform_string(platform, CL_PLATFORM_NAME));
    t.device_name = strip(device_string(device, CL_DEVICE_NAME));
    t.vendor = strip(device_string(device, CL_DEVICE_VENDOR));
    t.driver_version = strip(device_string(device, CL_DRIVER_VERSION));
    t.opencl_version = strip(device_string(device, CL_DEVICE_VERSION));
    t.is_gpu = (device_value<cl_device_type>(device, CL_DEVICE_TYPE) & CL_DEVICE_TYPE_GPU) != 0;
    t.compute_units = device_value<cl_uint>(device, CL_DEVICE_MAX_COMPUTE_UNITS);
    t.local_mem_size = device_value<cl_ulong>(device, CL_DEVICE_LOCAL_MEM_SIZE);
    t.max_work_group_size = device_value<std::size_t>(device, CL_DEVICE_MAX_WORK_GROUP_SIZE);
    std::string v = lower(t.vendor);
    if (t.is_gpu && v.find("nvidia") != std::string::npos) {
        t.wavefront = 32;
    } else if (t.is_gpu && (v.find("amd") != std::string::npos ||
                            v.find("advanced micro") != std::string::npos)) {
        t.wavefront = 64;
    } else if (t.is_gpu) {  // (rbgen.device: the vendor queries where a driver offers them)
        for (cl_device_info query : {cl_device_info(0x4003), cl_device_info(0x4043)}) {
            cl_uint width = 0;
            if (clGetDeviceInfo(device, query, sizeof width, &width, nullptr) == CL_SUCCESS) {
                t.wavefront = static_cast<int>(width);
                break;
            }
        }
    }
    return t;
}

std::vector<cl_device_id> all_devices() {
    cl_uint count = 0;
    if (clGetPlatformIDs(0, nullptr, &count) != CL_SUCCESS || count == 0) return {};
    std::vector<cl_platform_id> platforms(count);
    check(clGetPlatformIDs(count, platforms.data(), nullptr), "clGetPlatformIDs");
    std::vector<cl_device_id> out;
    for (cl_platform_id p : platforms) {
        cl_uint n = 0;
        if (clGetDeviceIDs(p, CL_DEVICE_TYPE_ALL, 0, nullptr, &n) != CL_SUCCESS || n == 0)
            continue;
        std::vector<cl_device_id> devices(n);
        check(clGetDeviceIDs(p, CL_DEVICE_TYPE_ALL, n, devices.data(), nullptr),
              "clGetDeviceIDs");
        out.insert(out.end(), devices.begin(), devices.end());
    }
    return out;
}

// ---------------------------------------------------------------------------- schedule model

// A number of the schedule: a constant, or a table over one capacity's rungs.
struct Number {
    int by = -1;                             // capacity index; -1: constant
    std::vector<const Json*> values;         // one (constant) or one per rung

    const Json& at(const std::vector<int>& rungs) const {
        if (by < 0) return *values[0];
        int r = rungs[by];
        if (r < 0 || r >= static_cast<int>(values.size()))
            values[0]->fail("has no value at rung " + std::to_string(r));
        return *values[r];
    }
};

struct Arg {
    char kind = 'n';  // 'b' buffer, 'n' null buffer, 's' scalar bytes, 'l' local bytes
    int buffer = -1;
    Number number;
    std::vector<uint8_t> bytes;  // resolved scalar
    std::size_t local = 0;       // resolved local size
};

struct Command {
    enum class Op { Launch, Fill, Copy, Write } op = Op::Launch;
    int kernel = -1;
    std::vector<Arg> args;
    Number global, local, pattern, offset, size, dst_offset, src_offset, data;
    int buffer = -1, dst = -1, src = -1;
    // resolved at the current rungs
    std::size_t g = 0, l = 0;
    std::size_t r_offset = 0, r_size = 0, r_dst_offset = 0, r_src_offset = 0;
    bool whole = false;
    std::vector<uint8_t> r_pattern, r_data;
};

struct Buffer {
    std::string name;
    Number size;
    std::string init;  // "zeros", "fill", "data"
    std::vector<uint8_t> pattern, data;
    std::vector<std::pair<int, int>> renew_on;  // (capacity, rung): reaching it reallocates
    cl_mem mem = nullptr;
    std::size_t bytes = 0;
};

struct Capacity {
    std::string name;
    int rung = 0, max = 0;
    int leader = -1;                 // followers: the capacity they follow
    std::vector<int> at_variants;    // followers: the variants whose steps catch them up
    std::string stage;               // grown: the stage that reports its need
};

struct Fatal {
    std::size_t word;
    uint32_t ok;
    std::string message;
};

struct Stage {
    std::string name;
    std::size_t offset = 0;
    std::vector<std::pair<int, std::size_t>> needs;  // (capacity, word)
    std::vector<Fatal> fatal;
};

struct InFlight {
    long n;
    int slot;
    cl_event read;
};

std::size_t as_size(const Json& j) {
    int64_t v = j.integer();
    if (v < 0) j.fail("is negative");
    return static_cast<std::size_t>(v);
}

}  // namespace

// ---------------------------------------------------------------------------- Host

struct Host::Impl {
    std::string dir, schedule_file;
    std::string text;  // schedule.json (the Json tree points into nothing: it owns its data)
    Json root;
    double dt = 0.0;
    std::string plan, device_label;

    cl_device_id device = nullptr;
    cl_context context = nullptr;
    cl_command_queue queue = nullptr;
    std::vector<cl_program> programs;
    std::vector<cl_kernel> kernels;
    std::vector<std::string> kernel_names;
    std::vector<std::vector<std::vector<uint8_t>>> set_args;  // per kernel: what it holds

    std::vector<Capacity> caps;
    std::map<std::string, int> cap_index;
    std::vector<int> rungs;
    std::vector<Buffer> buffers;
    std::vector<std::vector<Command>> variants, undo;
    long prologue = 0, cycle = 1;

    int report_buffer = -1;
    std::size_t report_words = 0;
    std::vector<Stage> stages;
    int steps_in_flight = 2, max_redos = 16;
    int64_t headroom_num = 5, headroom_den = 4;
    std::vector<cl_mem> pinned_buffers;
    std::vector<uint32_t*> pinned;
    std::deque<InFlight> in_flight;

    int body_buffer = -1;
    std::size_t body_count = 0, body_stride = 0;
    std::map<std::string, std::size_t> body_fields;

    long n = 0;  // the next step's index in the sequence
    int overflows = 0;
    HostTimes times;
    bool profile = false;
    std::vector<cl_event> profiled;  // (with profile: every command's event)

    ~Impl() {
        if (queue) clFinish(queue);
        for (auto& e : in_flight) clReleaseEvent(e.read);
        for (cl_event e : profiled) clReleaseEvent(e);
        for (std::size_t i = 0; i < pinned_buffers.size(); ++i) {
            if (queue && pinned[i])
                clEnqueueUnmapMemObject(queue, pinned_buffers[i], pinned[i], 0, nullptr, nullptr);
        }
        if (queue) clFinish(queue);
        for (cl_mem m : pinned_buffers) clReleaseMemObject(m);
        for (auto& b : buffers)
            if (b.mem) clReleaseMemObject(b.mem);
        for (cl_kernel k : kernels) clReleaseKernel(k);
        for (cl_program p : programs) clReleaseProgram(p);
        if (queue) clReleaseCommandQueue(queue);
        if (context) clReleaseContext(context);
    }

    // ------------------------------------------------------------------ loading
    void load(const HostOptions& options) {
        schedule_file = dir + "/schedule.json";
        text = read_file(schedule_file, "the schedule");
        g_json_file = schedule_file;
        root = JsonParser(text, schedule_file).parse();
        if (!root.is_object() || !root.find("format") || !root["format"].is_string() ||
            root["format"].str() != "rbgen-schedule")
            throw Error(schedule_file + " is not an rbgen schedule (no \"format\": "
                        "\"rbgen-schedule\")");
        int64_t version = root["version"].integer();
        if (version != kScheduleVersion)
            throw Error(schedule_file + " has schedule format version " + std::to_string(version) +
                        "; this runtime reads version " + std::to_string(kScheduleVersion) +
                        ". Build the runtime from the rbgen that made the export (rbgen/host/ "
                        "in its package), or export the World again with this one");
        check_files();
        choose_device(options);
        dt = root["dt"].real();
        plan = root["plan"].str();
        load_capacities(options);
        load_buffers();
        load_steps();
        load_report();
        const Json& bodies = root["bodies"];
        body_buffer = static_cast<int>(bodies["buffer"].integer());
        body_count = as_size(bodies["count"]);
        body_stride = as_size(bodies["stride"]);
        for (const auto& f : bodies["fields"].fields) body_fields[f.first] = as_size(f.second);
        build_programs();
        allocate_all();
        check(clFinish(queue), "clFinish");
    }

    void check_files() {
        for (const auto& f : root["files"].fields) {
            std::string path = dir + "/" + f.first;
            std::string content = read_file(path, "listed in schedule.json");
            if (sha256_hex(content) != f.second.str())
                throw Error(path + " is corrupted: its SHA-256 differs from the one schedule.json "
                            "lists (export the World again)");
        }
    }

    void choose_device(const HostOptions& options) {
        const Json& want = root["device"];
        std::string fingerprint = want["fingerprint"].str();
        std::vector<cl_device_id> devices = all_devices();
        std::string available;
        for (cl_device_id d : devices) {
            DeviceTraits t = traits_of(d);
            std::string label = t.platform_name + " " + t.device_name;
            std::string f = t.fingerprint();
            available += "\n  " + label + " (fingerprint " + f + ", driver " + t.driver_version + ")";
            if (f != fingerprint) continue;
            if (!options.device.empty() &&
                lower(label).find(lower(options.device)) == std::string::npos)
                continue;
            if (!device) {
                device = d;
                device_label = t.device_name + " [" + t.platform_name + "], driver " +
                               t.driver_version;
            }
        }
        if (!device)
            throw Error("this export was made for " + want["device_name"].str() + " [" +
                        want["platform_name"].str() + "], driver " +
                        want["driver_version"].str() + " (fingerprint " + fingerprint +
                        "), which is not here" +
                        (options.device.empty() ? "" : " matching '" + options.device + "'") +
                        ". Devices here:" + (available.empty() ? "\n  (none)" : available) +
                        "\nA schedule replays kernels built and tuned for one device and driver: "
                        "export it again on this machine from rbgen's sources (pip install "
                        "rbgen; `rbgen info` lists the devices, --device picks one): " +
                        (root.find("command") ? root["command"].str() : std::string("rbgen export --world SCENE --out DIR")));
        cl_int err = CL_SUCCESS;
        context = clCreateContext(nullptr, 1, &device, nullptr, nullptr, &err);
        check(err, "clCreateContext");
        profile = options.profile;
        queue = clCreateCommandQueue(context, device, profile ? CL_QUEUE_PROFILING_ENABLE : 0,
                                     &err);
        check(err, "clCreateCommandQueue");
    }

    Number number(const Json& j) {
        Number out;
        if (j.is_object() && j.find("by")) {
            const std::string& name = j["by"].str();
            auto it = cap_index.find(name);
            if (it == cap_index.end()) j["by"].fail("names no capacity ('" + name + "')");
            out.by = it->second;
            for (const Json& v : j["values"].array()) out.values.push_back(&v);
            if (static_cast<int>(out.values.size()) <= caps[out.by].max)
                j["values"].fail("has fewer values than the capacity's rungs");
        } else {
            out.values.push_back(&j);
        }
        return out;
    }

    void load_capacities(const HostOptions& options) {
        for (const Json& c : root["capacities"].array()) {
            Capacity cap;
            cap.name = c["name"].str();
            cap.rung = static_cast<int>(c["initial"].integer());
            cap.max = static_cast<int>(c["max"].integer());
            cap.stage = c["stage"].str();
            cap_index[cap.name] = static_cast<int>(caps.size());
            caps.push_back(cap);
        }
        for (const auto& start : options.start_rungs) {
            auto it = cap_index.find(start.first);
            if (it == cap_index.end() || caps[it->second].leader >= 0)
                throw Error("no capacity named '" + start.first + "' in " + schedule_file);
            Capacity& cap = caps[it->second];
            if (start.second < 0 || start.second > cap.max)
                throw Error("capacity " + cap.name + " can start at rungs 0 to " +
                            std::to_string(cap.max) + " (2^rung), not " +
                            std::to_string(start.second));
            cap.rung = start.second;
        }
        for (const Json& f : root["followers"].array()) {
            Capacity cap;
            cap.name = f["name"].str();
            auto it = cap_index.find(f["follows"].str());
            if (it == cap_index.end()) f["follows"].fail("names no capacity");
            cap.leader = it->second;
            cap.rung = caps[cap.leader].rung;
            cap.max = caps[cap.leader].max;
            for (const Json& v : f["at_variants"].array())
                cap.at_variants.push_back(static_cast<int>(v.integer()));
            cap_index[cap.name] = static_cast<int>(caps.size());
            caps.push_back(cap);
        }
        for (const Capacity& c : caps) rungs.push_back(c.rung);
    }

    void load_buffers() {
        for (const Json& b : root["buffers"].array()) {
            Buffer buf;
            buf.name = b["name"].str();
            buf.size = number(b["size"]);
            const Json& init = b["init"];
            buf.init = init["kind"].str();
            if (buf.init == "fill") {
                buf.pattern = from_hex(init["pattern"].str(), init["pattern"]);
            } else if (buf.init == "data") {
                std::string content = read_file(dir + "/" + init["file"].str(), "a buffer's data");
                buf.data.assign(content.begin(), content.end());
            } else if (buf.init != "zeros") {
                init["kind"].fail("is not zeros, fill or data");
            }
            const Json& renew = b["renew_on"];
            if (!renew.is_object()) renew.fail("is not an object");
            for (const auto& r : renew.fields) {
                auto it = cap_index.find(r.first);
                if (it == cap_index.end()) renew.fail("names no capacity " + r.first);
                for (const Json& rung : r.second.array())
                    buf.renew_on.emplace_back(it->second, static_cast<int>(rung.integer()));
            }
            buffers.push_back(std::move(buf));
        }
    }

    int buffer_ref(const Json& j) {
        int64_t b = j.integer();
        if (b < 0 || b >= static_cast<int64_t>(buffers.size())) j.fail("names no buffer");
        return static_cast<int>(b);
    }

    std::vector<Command> commands(const Json& list) {
        std::vector<Command> out;
        for (const Json& c : list.array()) {
            Command cmd;
            const std::string& op = c["op"].str();
            if (op == "launch") {
                cmd.op = Command::Op::Launch;
                int64_t k = c["kernel"].integer();
                if (k < 0 || k >= static_cast<int64_t>(root["kernels"].array().size()))
                    c["kernel"].fail("names no kernel");
                cmd.kernel = static_cast<int>(k);
                for (const Json& a : c["args"].array()) {
                    Arg arg;
                    const std::string& kind = a[0].str();
                    arg.kind = kind.empty() ? '?' : kind[0];
                    if (arg.kind == 'b') arg.buffer = buffer_ref(a[1]);
                    else if (arg.kind == 's' || arg.kind == 'l') arg.number = number(a[1]);
                    else if (arg.kind != 'n') a[0].fail("is not b, n, s or l");
                    cmd.args.push_back(std::move(arg));
                }
                cmd.global = number(c["global"]);
                cmd.local = number(c["local"]);
            } else if (op == "fill") {
                cmd.op = Command::Op::Fill;
                cmd.buffer = buffer_ref(c["buffer"]);
                cmd.pattern = number(c["pattern"]);
                cmd.offset = number(c["offset"]);
                cmd.size = number(c["size"]);
            } else if (op == "copy") {
                cmd.op = Command::Op::Copy;
                cmd.dst = buffer_ref(c["dst"]);
                cmd.src = buffer_ref(c["src"]);
                cmd.dst_offset = number(c["dst_offset"]);
                cmd.src_offset = number(c["src_offset"]);
                cmd.size = number(c["size"]);
            } else if (op == "write") {
                cmd.op = Command::Op::Write;
                cmd.buffer = buffer_ref(c["buffer"]);
                cmd.offset = number(c["offset"]);
                cmd.data = number(c["data"]);
            } else {
                c["op"].fail("is not launch, fill, copy or write");
            }
            out.push_back(std::move(cmd));
        }
        return out;
    }

    void load_steps() {
        const Json& steps = root["steps"];
        prologue = static_cast<long>(steps["prologue"].integer());
        cycle = static_cast<long>(steps["cycle"].integer());
        if (cycle < 1) steps["cycle"].fail("must be at least 1");
        for (const Json& v : steps["variants"].array()) variants.push_back(commands(v));
        for (const Json& v : steps["undo"].array()) undo.push_back(commands(v));
        if (static_cast<long>(variants.size()) != prologue + cycle ||
            undo.size() != variants.size())
            steps.fail("must list prologue + cycle variants and an undo per variant");
    }

    void load_report() {
        const Json& r = root["report"];
        report_buffer = buffer_ref(r["buffer"]);
        report_words = as_size(r["words"]);
        steps_in_flight = static_cast<int>(r["steps_in_flight"].integer());
        max_redos = static_cast<int>(r["max_redos"].integer());
        headroom_num = r["headroom"][0].integer();
        headroom_den = r["headroom"][1].integer();
        for (const Json& s : r["stages"].array()) {
            Stage st;
            st.name = s["name"].str();
            st.offset = as_size(s["offset"]);
            for (const auto& c : s["capacities"].fields) {
                auto it = cap_index.find(c.first);
                if (it == cap_index.end()) s["capacities"].fail("names no capacity " + c.first);
                st.needs.emplace_back(it->second, as_size(c.second));
            }
            for (const Json& f : s["fatal"].array())
                st.fatal.push_back({as_size(f["word"]), static_cast<uint32_t>(f["ok"].integer()),
                                    f["message"].str()});
            stages.push_back(std::move(st));
        }
        cl_int err = CL_SUCCESS;
        for (int i = 0; i < steps_in_flight; ++i) {
            cl_mem m = clCreateBuffer(context, CL_MEM_ALLOC_HOST_PTR, 4 * report_words, nullptr,
                                      &err);
            check(err, "clCreateBuffer (the report's host copy)");
            void* p = clEnqueueMapBuffer(queue, m, CL_TRUE, CL_MAP_READ | CL_MAP_WRITE, 0,
                                         4 * report_words, 0, nullptr, nullptr, &err);
            check(err, "clEnqueueMapBuffer (the report's host copy)");
            pinned_buffers.push_back(m);
            pinned.push_back(static_cast<uint32_t*>(p));
        }
    }

    void build_programs() {
        cl_int err = CL_SUCCESS;
        for (const Json& p : root["programs"].array()) {
            std::string path = dir + "/" + p["file"].str();
            std::string source = read_file(path, "a kernel program");
            const char* src = source.c_str();
            std::size_t length = source.size();
            cl_program program = clCreateProgramWithSource(context, 1, &src, &length, &err);
            check(err, "clCreateProgramWithSource " + path);
            std::string opts;
            for (const Json& o : p["build_options"].array()) opts += o.str() + " ";
            err = clBuildProgram(program, 1, &device, opts.c_str(), nullptr, nullptr);
            if (err != CL_SUCCESS) {
                std::size_t size = 0;
                clGetProgramBuildInfo(program, device, CL_PROGRAM_BUILD_LOG, 0, nullptr, &size);
                std::string log(size, '\0');
                clGetProgramBuildInfo(program, device, CL_PROGRAM_BUILD_LOG, size, &log[0], nullptr);
                clReleaseProgram(program);
                throw Error("building " + path + " (options '" + opts + "') failed:\n" + log);
            }
            programs.push_back(program);
        }
        for (const Json& k : root["kernels"].array()) {
            int64_t p = k["program"].integer();
            if (p < 0 || p >= static_cast<int64_t>(programs.size())) k["program"].fail("names no program");
            const std::string& name = k["name"].str();
            cl_kernel kernel = clCreateKernel(programs[p], name.c_str(), &err);
            check(err, "clCreateKernel " + name);
            cl_uint count = 0;
            check(clGetKernelInfo(kernel, CL_KERNEL_NUM_ARGS, sizeof count, &count, nullptr),
                  "clGetKernelInfo");
            kernels.push_back(kernel);
            kernel_names.push_back(name);
            set_args.emplace_back(count);
        }
    }

    // ------------------------------------------------------------------ buffers
    std::size_t evaluate_size(const Number& number) const {
        const Json& j = number.at(rungs);
        return as_size(j);
    }

    void allocate(Buffer& b) {
        if (b.mem) clReleaseMemObject(b.mem);
        b.mem = nullptr;
        b.bytes = evaluate_size(b.size);
        if (b.bytes == 0) throw Error("buffer " + b.name + " has size 0 in " + schedule_file);
        cl_int err = CL_SUCCESS;
        b.mem = clCreateBuffer(context, CL_MEM_READ_WRITE, b.bytes, nullptr, &err);
        check(err, "clCreateBuffer " + b.name + " (" + std::to_string(b.bytes) + " bytes)");
        if (b.init == "data") {
            if (b.data.size() != b.bytes)
                throw Error("the data file of buffer " + b.name + " holds " +
                            std::to_string(b.data.size()) + " bytes, the buffer " +
                            std::to_string(b.bytes));
            check(clEnqueueWriteBuffer(queue, b.mem, CL_TRUE, 0, b.bytes, b.data.data(), 0,
                                       nullptr, nullptr), "clEnqueueWriteBuffer " + b.name);
        } else {
            static const uint8_t zero = 0;
            const uint8_t* pattern = b.init == "fill" ? b.pattern.data() : &zero;
            std::size_t width = b.init == "fill" ? b.pattern.size() : 1;
            if (b.bytes % width) throw Error("buffer " + b.name + ": its size is no multiple of its fill pattern");
            check(clEnqueueFillBuffer(queue, b.mem, pattern, width, 0, b.bytes, 0, nullptr,
                                      nullptr), "clEnqueueFillBuffer " + b.name);
        }
    }

    void allocate_all() {
        for (Buffer& b : buffers) allocate(b);
        resolve();
    }

    // Capacity `cap` went from rung `from` to its rung now: the buffers Python reallocates
    // when it reaches one of the rungs between get new allocations.
    void renew(int cap, int from) {
        for (Buffer& b : buffers)
            for (const auto& r : b.renew_on)
                if (r.first == cap && r.second > from && r.second <= rungs[cap]) {
                    allocate(b);
                    break;
                }
    }

    // ------------------------------------------------------------------ numbers
    void resolve(Command& c) {
        auto size_of = [&](const Number& n) { return as_size(n.at(rungs)); };
        switch (c.op) {
            case Command::Op::Launch: {
                for (Arg& a : c.args) {
                    if (a.kind == 's') {
                        const Json& j = a.number.at(rungs);
                        a.bytes = from_hex(j.str(), j);
                    } else if (a.kind == 'l') {
                        a.local = size_of(a.number);
                    }
                }
                c.g = size_of(c.global);
                const Json& l = c.local.at(rungs);
                c.l = l.is_null() ? 0 : as_size(l);
                break;
            }
            case Command::Op::Fill:
            case Command::Op::Copy: {
                const Json& size = c.size.at(rungs);
                c.whole = size.is_string() && size.str() == "whole";
                if (!c.whole) c.r_size = as_size(size);
                if (c.op == Command::Op::Fill) {
                    const Json& p = c.pattern.at(rungs);
                    c.r_pattern = from_hex(p.str(), p);
                    c.r_offset = size_of(c.offset);
                } else {
                    c.r_dst_offset = size_of(c.dst_offset);
                    c.r_src_offset = size_of(c.src_offset);
                }
                break;
            }
            case Command::Op::Write: {
                c.r_offset = size_of(c.offset);
                const Json& d = c.data.at(rungs);
                c.r_data = from_hex(d.str(), d);
                break;
            }
        }
    }

    void resolve() {
        for (auto& list : variants)
            for (Command& c : list) resolve(c);
        for (auto& list : undo)
            for (Command& c : list) resolve(c);
    }

    // ------------------------------------------------------------------ enqueueing
    void set_arg(int kernel, cl_uint index, const void* value, std::size_t size,
                 const uint8_t* key, std::size_t key_size) {
        std::vector<uint8_t>& held = set_args[kernel][index];
        if (held.size() == key_size && std::memcmp(held.data(), key, key_size) == 0) return;
        cl_int err = clSetKernelArg(kernels[kernel], index, size, value);
        if (err != CL_SUCCESS)
            check(err, "clSetKernelArg " + kernel_names[kernel] + " argument " +
                           std::to_string(index));
        held.assign(key, key + key_size);
    }

    void run(const Command& c) {
        cl_event event = nullptr;
        cl_event* timed = profile ? &event : nullptr;
        enqueue(c, timed);
        if (event) profiled.push_back(event);
    }

    void enqueue(const Command& c, cl_event* timed) {
        switch (c.op) {
            case Command::Op::Launch: {
                for (cl_uint i = 0; i < c.args.size(); ++i) {
                    const Arg& a = c.args[i];
                    if (a.kind == 'b' || a.kind == 'n') {
                        cl_mem m = a.kind == 'b' ? buffers[a.buffer].mem : nullptr;
                        uint8_t key[1 + sizeof(cl_mem)];
                        key[0] = 'b';
                        std::memcpy(key + 1, &m, sizeof m);
                        set_arg(c.kernel, i, &m, sizeof m, key, sizeof key);
                    } else if (a.kind == 's') {
                        set_arg(c.kernel, i, a.bytes.data(), a.bytes.size(), a.bytes.data(),
                                a.bytes.size());
                    } else {
                        uint8_t key[1 + sizeof(std::size_t)];
                        key[0] = 'l';
                        std::memcpy(key + 1, &a.local, sizeof a.local);
                        set_arg(c.kernel, i, nullptr, a.local, key, sizeof key);
                    }
                }
                cl_int err = clEnqueueNDRangeKernel(queue, kernels[c.kernel], 1, nullptr, &c.g,
                                                    c.l ? &c.l : nullptr, 0, nullptr, timed);
                if (err != CL_SUCCESS)
                    check(err, "clEnqueueNDRangeKernel " + kernel_names[c.kernel] + " over " +
                                   std::to_string(c.g) + " work-items");
                break;
            }
            case Command::Op::Fill: {
                const Buffer& b = buffers[c.buffer];
                check(clEnqueueFillBuffer(queue, b.mem, c.r_pattern.data(), c.r_pattern.size(),
                                          c.whole ? 0 : c.r_offset, c.whole ? b.bytes : c.r_size,
                                          0, nullptr, timed),
                      "clEnqueueFillBuffer " + b.name);
                break;
            }
            case Command::Op::Copy: {
                const Buffer& d = buffers[c.dst];
                const Buffer& s = buffers[c.src];
                std::size_t size = c.whole ? std::min(d.bytes, s.bytes) : c.r_size;
                check(clEnqueueCopyBuffer(queue, s.mem, d.mem, c.whole ? 0 : c.r_src_offset,
                                          c.whole ? 0 : c.r_dst_offset, size, 0, nullptr, timed),
                      "clEnqueueCopyBuffer " + s.name + " -> " + d.name);
                break;
            }
            case Command::Op::Write: {
                const Buffer& b = buffers[c.buffer];
                check(clEnqueueWriteBuffer(queue, b.mem, CL_FALSE, c.r_offset, c.r_data.size(),
                                           c.r_data.data(), 0, nullptr, timed),
                      "clEnqueueWriteBuffer " + b.name);
                break;
            }
        }
    }

    int variant(long step) const {
        return static_cast<int>(step < prologue ? step : prologue + (step - prologue) % cycle);
    }

    void enqueue_step() {
        int v = variant(n);
        bool changed = false;
        for (std::size_t i = 0; i < caps.size(); ++i) {
            Capacity& c = caps[i];
            if (c.leader < 0 || rungs[i] >= rungs[c.leader]) continue;
            if (std::find(c.at_variants.begin(), c.at_variants.end(), v) == c.at_variants.end())
                continue;
            int from = rungs[i];
            rungs[i] = rungs[c.leader];
            renew(static_cast<int>(i), from);
            changed = true;
        }
        if (changed) resolve();
        for (const Command& c : variants[v]) run(c);
        int slot = static_cast<int>(n % steps_in_flight);
        cl_event read = nullptr;
        check(clEnqueueReadBuffer(queue, buffers[report_buffer].mem, CL_FALSE, 0,
                                  4 * report_words, pinned[slot], 0, nullptr, &read),
              "clEnqueueReadBuffer (the step report)");
        in_flight.push_back({n, slot, read});
        ++n;
    }

    template <typename F>
    void waiting(F f) {
        auto t0 = std::chrono::steady_clock::now();
        f();
        times.waiting += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    }

    void check_in_flight(std::size_t keep) {
        int redone = 0;
        while (in_flight.size() > keep) {
            InFlight entry = in_flight.front();
            waiting([&] { check(clWaitForEvents(1, &entry.read), "clWaitForEvents (the step report)"); });
            const uint32_t* words = pinned[entry.slot];
            std::vector<std::pair<int, uint64_t>> problems;
            for (const Stage& s : stages) {
                for (const Fatal& f : s.fatal) {
                    uint32_t w = words[s.offset + f.word];
                    if (w != f.ok)
                        throw Error("step " + std::to_string(entry.n) + ", stage " + s.name +
                                    ": " + f.message + " (report word " + std::to_string(w) + ")");
                }
                for (const auto& need : s.needs) {
                    uint64_t want = words[s.offset + need.second];
                    if (want > (uint64_t(1) << rungs[need.first]))
                        problems.emplace_back(need.first, want);
                }
            }
            if (problems.empty()) {
                clReleaseEvent(entry.read);
                in_flight.pop_front();
                continue;
            }
            if (++redone > max_redos)
                throw Error("a step still overflowed after " + std::to_string(max_redos) +
                            " redos with grown buffers");
            waiting([&] { check(clFinish(queue), "clFinish"); });
            long first = entry.n;
            std::size_t count = in_flight.size();
            for (auto& e : in_flight) clReleaseEvent(e.read);
            in_flight.clear();
            for (const Command& c : undo[variant(first)]) run(c);  // restore, rewind
            n = first;
            ++overflows;
            for (const auto& p : problems) grow(p.first, p.second);
            resolve();
            for (std::size_t k = 0; k < count; ++k) enqueue_step();
        }
    }

    void grow(int cap, uint64_t need) {
        Capacity& c = caps[cap];
        uint64_t target = (need * headroom_num + headroom_den - 1) / headroom_den;
        int rung = 0;
        while ((uint64_t(1) << rung) < target) ++rung;
        if (rung > c.max)
            throw Error("capacity " + c.name + " must hold " + std::to_string(need) +
                        " (stage " + c.stage + "), more than this export covers (2^" +
                        std::to_string(c.max) + " = " + std::to_string(uint64_t(1) << c.max) +
                        "): export the World again with a larger --grow-rungs");
        int from = rungs[cap];
        rungs[cap] = std::max(rung, rungs[cap] + 1);
        renew(cap, from);
    }

    std::vector<float> field(const char* name, int lanes) {
        auto it = body_fields.find(name);
        if (it == body_fields.end()) throw Error(schedule_file + ": bodies.fields has no " + name);
        check_in_flight(0);
        waiting([&] { check(clFinish(queue), "clFinish"); });
        std::vector<uint8_t> raw(body_count * body_stride);
        check(clEnqueueReadBuffer(queue, buffers[body_buffer].mem, CL_TRUE, 0, raw.size(),
                                  raw.data(), 0, nullptr, nullptr), "clEnqueueReadBuffer (bodies)");
        std::vector<float> out(body_count * lanes);
        for (std::size_t i = 0; i < body_count; ++i)
            std::memcpy(&out[i * lanes], &raw[i * body_stride + it->second], 4 * lanes);
        return out;
    }
};

Host::Host(const std::string& directory, const HostOptions& options) : impl_(new Impl) {
    impl_->dir = directory;
    impl_->load(options);
}

Host::~Host() = default;

void Host::step() {
    auto t0 = std::chrono::steady_clock::now();
    impl_->check_in_flight(static_cast<std::size_t>(impl_->steps_in_flight - 1));
    impl_->enqueue_step();
    impl_->times.in_step +=
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

void Host::finish() {
    auto t0 = std::chrono::steady_clock::now();
    impl_->check_in_flight(0);
    impl_->waiting([&] { check(clFinish(impl_->queue), "clFinish"); });
    impl_->times.in_step +=
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

std::size_t Host::body_count() const { return impl_->body_count; }
std::vector<float> Host::positions() { return impl_->field("position", 3); }
std::vector<float> Host::orientations() { return impl_->field("orientation", 4); }
std::vector<float> Host::linear_velocities() { return impl_->field("linear_velocity", 3); }
std::vector<float> Host::angular_velocities() { return impl_->field("angular_velocity", 3); }
std::vector<float> Host::inverse_masses() { return impl_->field("inv_mass", 1); }
long Host::steps() const { return impl_->n; }
int Host::overflows() const { return impl_->overflows; }
std::string Host::device_name() const { return impl_->device_label; }
std::string Host::plan() const { return impl_->plan; }
double Host::dt() const { return impl_->dt; }
const HostTimes& Host::times() const { return impl_->times; }

double Host::device_seconds() {
    if (!impl_->profile) throw Error("device_seconds needs HostOptions::profile");
    finish();
    double total = 0.0;
    for (cl_event e : impl_->profiled) {
        cl_ulong start = 0, end = 0;
        check(clGetEventProfilingInfo(e, CL_PROFILING_COMMAND_START, sizeof start, &start, nullptr),
              "clGetEventProfilingInfo");
        check(clGetEventProfilingInfo(e, CL_PROFILING_COMMAND_END, sizeof end, &end, nullptr),
              "clGetEventProfilingInfo");
        total += 1e-9 * static_cast<double>(end - start);
        clReleaseEvent(e);
    }
    impl_->profiled.clear();
    return total;
}

std::map<std::string, long> Host::capacities() const {
    std::map<std::string, long> out;
    for (std::size_t i = 0; i < impl_->caps.size(); ++i)
        out[impl_->caps[i].name] = 1L << impl_->rungs[i];
    return out;
}

std::string device_fingerprint(cl_device_id device) { return traits_of(device).fingerprint(); }

}  // namespace rbgen
