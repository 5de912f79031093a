// Reference C++ subscriber for the streamfix wire protocol v1 (see ../SPEC.md).
//
// The stand-in for a game engine: libzmq (C API) + msgpack-c (C API, msgpack.h),
// both from Debian's system packages (libzmq3-dev, libmsgpack-dev). No other
// dependency: the small JSON reader below exists only to check test vectors.
//
//   subscriber --vectors DIR
//       decode every vector listed in DIR/index.json, compare with its .json meaning,
//       check that invalid vectors are rejected with the stated reason; exit 1 on
//       any mismatch.
//   subscriber --connect tcp://127.0.0.1:PORT [--topic PREFIX]... [--count N] [--timeout S]
//       subscribe (default prefix "sf/"; "sf/meta/" is always added to learn
//       skeletons) and print one line per frame:
//       <topic> seq=<n> t_sensor_ns=<t> bodies=<k> [<id>:<observed>/<recovered>/<missing>]... [filled]
//       Exit 0 once N frames were printed, 2 if the timeout came first.
//
// Decoding rules (SPEC.md sections 3, 4, 6): blobs are little-endian float32; a
// joint with a non-finite coordinate is missing (confidence 0); unknown keys are
// ignored; a newer major version, wrong blob length, unknown skeleton, truncated or
// non-msgpack payload is rejected with a reason and skipped.

#include <msgpack.h>
#include <zmq.h>

#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace {

const int64_t kSupportedVersion = 1;

// ------------------------------------------------------------------ decoded types

struct Body {
    int64_t id = 0;
    std::vector<float> positions;   // J*3, NaN for missing joints
    std::vector<float> confidence;  // J
    bool has_recovered = false;
    std::vector<uint8_t> recovered;  // J (0/1)
};

struct Frame {
    std::string stream, skeleton;
    uint64_t seq = 0;
    int64_t t_sensor_ns = 0, t_publish_ns = 0;
    uint64_t joints = 0;
    bool filled = false;
    uint64_t epoch = 0, dropped = 0;  // optional keys (SPEC 4.1); 0 when absent
    std::vector<Body> bodies;
};

struct SkeletonMsg {
    std::string stream, skeleton, units;
    std::vector<std::string> joint_names;
    std::vector<std::pair<int64_t, int64_t>> bones;
    double rate_hz = 0;
    int64_t t_publish_ns = 0;
};

struct Rejected : std::runtime_error {
    std::string reason;
    Rejected(const std::string& r, const std::string& text) : std::runtime_error(r + ": " + text), reason(r) {}
};

// ------------------------------------------------------------------ msgpack helpers

const msgpack_object* map_get(const msgpack_object& map, const char* key) {
    size_t n = std::strlen(key);
    for (uint32_t i = 0; i < map.via.map.size; ++i) {
        const msgpack_object& k = map.via.map.ptr[i].key;
        if (k.type == MSGPACK_OBJECT_STR && k.via.str.size == n && std::memcmp(k.via.str.ptr, key, n) == 0)
            return &map.via.map.ptr[i].val;
    }
    return nullptr;
}

bool is_int(const msgpack_object* o) {
    return o && (o->type == MSGPACK_OBJECT_POSITIVE_INTEGER || o->type == MSGPACK_OBJECT_NEGATIVE_INTEGER);
}

int64_t get_i64(const msgpack_object& m, const char* key) {
    const msgpack_object* o = map_get(m, key);
    if (!is_int(o)) throw Rejected("field", std::string("'") + key + "' missing or not an integer");
    if (o->type == MSGPACK_OBJECT_POSITIVE_INTEGER) {
        if (o->via.u64 > static_cast<uint64_t>(INT64_MAX)) throw Rejected("field", std::string("'") + key + "' out of int64 range");
        return static_cast<int64_t>(o->via.u64);
    }
    return o->via.i64;
}

uint64_t get_u64(const msgpack_object& m, const char* key) {
    const msgpack_object* o = map_get(m, key);
    if (!is_int(o)) throw Rejected("field", std::string("'") + key + "' missing or not an integer");
    if (o->type == MSGPACK_OBJECT_NEGATIVE_INTEGER) throw Rejected("field", std::string("'") + key + "' is negative");
    return o->via.u64;
}

std::string get_str(const msgpack_object& m, const char* key) {
    const msgpack_object* o = map_get(m, key);
    if (!o || o->type != MSGPACK_OBJECT_STR) throw Rejected("field", std::string("'") + key + "' missing or not a string");
    return std::string(o->via.str.ptr, o->via.str.size);
}

bool valid_stream(const std::string& s) {
    if (s.empty() || s.size() > 64) return false;
    for (char c : s)
        if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '.' || c == ':' || c == '-')) return false;
    return true;
}

float read_f32le(const char* p) {
    uint32_t u = static_cast<uint32_t>(static_cast<unsigned char>(p[0])) |
                 static_cast<uint32_t>(static_cast<unsigned char>(p[1])) << 8 |
                 static_cast<uint32_t>(static_cast<unsigned char>(p[2])) << 16 |
                 static_cast<uint32_t>(static_cast<unsigned char>(p[3])) << 24;
    float f;
    std::memcpy(&f, &u, 4);
    return f;
}

// Built-in skeletons (SPEC.md section 5): name -> joint count.
std::map<std::string, size_t> builtin_joints() {
    return {{"kinect_v2", 25}, {"azure_kinect", 32}, {"mediapipe_pose", 33}};
}

// The decoder keeps the skeletons announced on sf/meta/.
struct Decoder {
    std::map<std::string, size_t> joints = builtin_joints();

    // Unpacks the payload; returns its message type. `keep` owns the memory.
    static std::string unpack(const std::string& payload, msgpack_unpacked& keep) {
        if (payload.empty()) throw Rejected("garbage", "empty payload");
        size_t off = 0;
        msgpack_unpack_return ret = msgpack_unpack_next(&keep, payload.data(), payload.size(), &off);
        if (ret == MSGPACK_UNPACK_CONTINUE) throw Rejected("truncated", "payload ends inside a msgpack value");
        if (ret != MSGPACK_UNPACK_SUCCESS && ret != MSGPACK_UNPACK_EXTRA_BYTES)
            throw Rejected("garbage", "not msgpack");
        if (off != payload.size()) throw Rejected("garbage", "bytes after the msgpack value");
        const msgpack_object& m = keep.data;
        if (m.type != MSGPACK_OBJECT_MAP) throw Rejected("garbage", "payload is not a map");
        int64_t v = get_i64(m, "v");
        if (v > kSupportedVersion || v < 1)
            throw Rejected("version", "protocol version " + std::to_string(v) + " is newer than supported 1");
        return get_str(m, "type");
    }

    Frame frame(const msgpack_object& m) {
        Frame f;
        f.stream = get_str(m, "stream");
        if (!valid_stream(f.stream)) throw Rejected("field", "bad stream id");
        f.seq = get_u64(m, "seq");
        f.t_sensor_ns = get_i64(m, "t_sensor_ns");
        f.t_publish_ns = get_i64(m, "t_publish_ns");
        f.skeleton = get_str(m, "skeleton");
        f.joints = get_u64(m, "joints");
        const msgpack_object* filled = map_get(m, "filled");
        if (!filled || filled->type != MSGPACK_OBJECT_BOOLEAN) throw Rejected("field", "'filled' missing or not a boolean");
        f.filled = filled->via.boolean;
        if (map_get(m, "epoch")) f.epoch = get_u64(m, "epoch");
        if (map_get(m, "dropped")) f.dropped = get_u64(m, "dropped");
        const msgpack_object* bodies = map_get(m, "bodies");
        if (!bodies || bodies->type != MSGPACK_OBJECT_ARRAY) throw Rejected("field", "'bodies' missing or not an array");
        if (bodies->via.array.size > 64) throw Rejected("field", "more than 64 bodies");
        auto it = joints.find(f.skeleton);
        if (it == joints.end()) throw Rejected("skeleton", "unknown skeleton '" + f.skeleton + "'");
        const size_t J = it->second;
        if (bodies->via.array.size > 0 && f.joints != J)
            throw Rejected("joints", "'joints' is " + std::to_string(f.joints) + ", skeleton '" + f.skeleton +
                                         "' has " + std::to_string(J));
        std::set<int64_t> ids;
        for (uint32_t i = 0; i < bodies->via.array.size; ++i) {
            const msgpack_object& b = bodies->via.array.ptr[i];
            if (b.type != MSGPACK_OBJECT_MAP) throw Rejected("field", "body is not a map");
            Body body;
            body.id = get_i64(b, "id");
            if (!ids.insert(body.id).second) throw Rejected("field", "duplicate body id " + std::to_string(body.id));
            const msgpack_object* pos = map_get(b, "pos");
            const msgpack_object* conf = map_get(b, "conf");
            const msgpack_object* rec = map_get(b, "rec");
            if (!pos || pos->type != MSGPACK_OBJECT_BIN) throw Rejected("field", "'pos' missing or not binary");
            if (!conf || conf->type != MSGPACK_OBJECT_BIN) throw Rejected("field", "'conf' missing or not binary");
            if (pos->via.bin.size != 12 * J)
                throw Rejected("joints", "body " + std::to_string(body.id) + ": positions blob has " +
                                             std::to_string(pos->via.bin.size) + " bytes, expected " + std::to_string(12 * J));
            if (conf->via.bin.size != 4 * J)
                throw Rejected("joints", "body " + std::to_string(body.id) + ": confidence blob has " +
                                             std::to_string(conf->via.bin.size) + " bytes, expected " + std::to_string(4 * J));
            if (rec) {
                if (rec->type != MSGPACK_OBJECT_BIN) throw Rejected("field", "'rec' not binary");
                if (rec->via.bin.size != J) throw Rejected("joints", "rec blob has wrong length");
                body.has_recovered = true;
                body.recovered.assign(rec->via.bin.ptr, rec->via.bin.ptr + J);
                for (auto& r : body.recovered) r = r ? 1 : 0;
            }
            body.positions.resize(3 * J);
            body.confidence.resize(J);
            for (size_t j = 0; j < J; ++j) {
                float c = read_f32le(conf->via.bin.ptr + 4 * j);
                c = std::isnan(c) ? 0.0f : std::fmin(1.0f, std::fmax(0.0f, c));
                bool finite = true;
                for (size_t k = 0; k < 3; ++k) {
                    float x = read_f32le(pos->via.bin.ptr + 12 * j + 4 * k);
                    finite = finite && std::isfinite(x);
                    body.positions[3 * j + k] = x;
                }
                if (!finite) {  // NaN/inf coordinate: missing joint, not an error
                    for (size_t k = 0; k < 3; ++k) body.positions[3 * j + k] = NAN;
                    c = 0.0f;
                }
                body.confidence[j] = c;
            }
            f.bodies.push_back(std::move(body));
        }
        return f;
    }

    SkeletonMsg skeleton(const msgpack_object& m) {
        SkeletonMsg s;
        s.stream = get_str(m, "stream");
        if (!valid_stream(s.stream)) throw Rejected("field", "bad stream id");
        s.skeleton = get_str(m, "skeleton");
        const msgpack_object* names = map_get(m, "joint_names");
        if (!names || names->type != MSGPACK_OBJECT_ARRAY) throw Rejected("field", "'joint_names' missing or not an array");
        std::set<std::string> unique;
        for (uint32_t i = 0; i < names->via.array.size; ++i) {
            const msgpack_object& n = names->via.array.ptr[i];
            if (n.type != MSGPACK_OBJECT_STR) throw Rejected("field", "joint name is not a string");
            s.joint_names.emplace_back(n.via.str.ptr, n.via.str.size);
            if (!unique.insert(s.joint_names.back()).second) throw Rejected("field", "duplicate joint name");
        }
        const int64_t J = static_cast<int64_t>(s.joint_names.size());
        const msgpack_object* bones = map_get(m, "bones");
        if (!bones || bones->type != MSGPACK_OBJECT_ARRAY) throw Rejected("field", "'bones' missing or not an array");
        for (uint32_t i = 0; i < bones->via.array.size; ++i) {
            const msgpack_object& b = bones->via.array.ptr[i];
            if (b.type != MSGPACK_OBJECT_ARRAY || b.via.array.size != 2 || !is_int(&b.via.array.ptr[0]) ||
                !is_int(&b.via.array.ptr[1]))
                throw Rejected("field", "bone is not a [parent, child] pair");
            int64_t p = b.via.array.ptr[0].via.i64, c = b.via.array.ptr[1].via.i64;
            if (p < 0 || c < 0 || p >= J || c >= J || p == c) throw Rejected("field", "bone does not join two joints");
            s.bones.emplace_back(p, c);
        }
        const msgpack_object* rate = map_get(m, "rate_hz");
        if (!rate) throw Rejected("field", "'rate_hz' missing");
        if (rate->type == MSGPACK_OBJECT_FLOAT32 || rate->type == MSGPACK_OBJECT_FLOAT64) s.rate_hz = rate->via.f64;
        else if (rate->type == MSGPACK_OBJECT_POSITIVE_INTEGER) s.rate_hz = static_cast<double>(rate->via.u64);
        else throw Rejected("field", "'rate_hz' not a number");
        if (!(s.rate_hz > 0) || !std::isfinite(s.rate_hz)) throw Rejected("field", "'rate_hz' not positive");
        s.units = get_str(m, "units");
        if (s.units != "m") throw Rejected("field", "'units' is not 'm'");
        s.t_publish_ns = map_get(m, "t_publish_ns") ? get_i64(m, "t_publish_ns") : 0;
        joints[s.skeleton] = s.joint_names.size();
        return s;
    }
};

// ------------------------------------------------------------------ tiny JSON reader

struct Json {
    enum Type { Null, Bool, Number, String, Array, Object } type = Null;
    bool b = false;
    double num = 0;
    bool is_integer = false;
    bool negative = false;
    uint64_t magnitude = 0;  // exact value of an integer literal
    std::string str;
    std::vector<Json> arr;
    std::vector<std::pair<std::string, Json>> obj;

    const Json& at(const std::string& key) const {
        for (const auto& kv : obj)
            if (kv.first == key) return kv.second;
        throw std::runtime_error("JSON key '" + key + "' missing");
    }
    bool has(const std::string& key) const {
        for (const auto& kv : obj)
            if (kv.first == key) return true;
        return false;
    }
    int64_t i64() const { return negative ? -static_cast<int64_t>(magnitude) : static_cast<int64_t>(magnitude); }
};

struct JsonParser {
    const std::string& s;
    size_t i = 0;
    explicit JsonParser(const std::string& text) : s(text) {}

    void ws() {
        while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    }
    [[noreturn]] void fail(const char* what) { throw std::runtime_error(std::string("JSON: ") + what + " at " + std::to_string(i)); }
    bool lit(const char* word) {
        size_t n = std::strlen(word);
        if (s.compare(i, n, word) == 0) {
            i += n;
            return true;
        }
        return false;
    }
    Json value() {
        ws();
        if (i >= s.size()) fail("unexpected end");
        Json v;
        char c = s[i];
        if (c == '{') {
            v.type = Json::Object;
            ++i;
            ws();
            if (s[i] == '}') { ++i; return v; }
            for (;;) {
                ws();
                Json k = value();
                if (k.type != Json::String) fail("object key");
                ws();
                if (s[i++] != ':') fail("expected ':'");
                v.obj.emplace_back(k.str, value());
                ws();
                if (s[i] == ',') { ++i; continue; }
                if (s[i] == '}') { ++i; return v; }
                fail("expected ',' or '}'");
            }
        }
        if (c == '[') {
            v.type = Json::Array;
            ++i;
            ws();
            if (s[i] == ']') { ++i; return v; }
            for (;;) {
                v.arr.push_back(value());
                ws();
                if (s[i] == ',') { ++i; continue; }
                if (s[i] == ']') { ++i; return v; }
                fail("expected ',' or ']'");
            }
        }
        if (c == '"') {
            v.type = Json::String;
            ++i;
            while (i < s.size() && s[i] != '"') {
                if (s[i] == '\\') {
                    ++i;
                    char e = s[i];
                    if (e == 'n') v.str += '\n';
                    else if (e == 't') v.str += '\t';
                    else if (e == 'u') {  // vectors are ASCII; keep \u00XX only
                        v.str += static_cast<char>(std::strtol(s.substr(i + 1, 4).c_str(), nullptr, 16));
                        i += 4;
                    } else v.str += e;
                    ++i;
                } else {
                    v.str += s[i++];
                }
            }
            ++i;
            return v;
        }
        if (lit("null")) return v;
        if (lit("true")) { v.type = Json::Bool; v.b = true; return v; }
        if (lit("false")) { v.type = Json::Bool; return v; }
        size_t start = i;
        while (i < s.size() && (std::isdigit(static_cast<unsigned char>(s[i])) || std::strchr("+-.eE", s[i]))) ++i;
        std::string tok = s.substr(start, i - start);
        if (tok.empty()) fail("bad value");
        v.type = Json::Number;
        v.num = std::strtod(tok.c_str(), nullptr);
        if (tok.find_first_of(".eE") == std::string::npos) {
            v.is_integer = true;
            v.negative = tok[0] == '-';
            v.magnitude = std::strtoull(tok.c_str() + (v.negative ? 1 : 0), nullptr, 10);
        }
        return v;
    }
};

Json read_json(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error("cannot open " + path);
    std::stringstream ss;
    ss << in.rdbuf();
    std::string text = ss.str();
    JsonParser p(text);
    return p.value();
}

std::string read_file(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error("cannot open " + path);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
}

// ------------------------------------------------------------------ vector checks

std::string compare_frame(const Frame& f, const Json& e) {
    if (e.at("type").str != "frame") return "expected a skeleton message, decoded a frame";
    if (f.stream != e.at("stream").str) return "stream differs";
    if (f.seq != e.at("seq").magnitude) return "seq differs";
    if (f.t_sensor_ns != e.at("t_sensor_ns").i64()) return "t_sensor_ns differs";
    if (f.t_publish_ns != e.at("t_publish_ns").i64()) return "t_publish_ns differs";
    if (f.skeleton != e.at("skeleton").str) return "skeleton differs";
    if (f.joints != e.at("joints").magnitude) return "joints differs";
    if (f.filled != e.at("filled").b) return "filled differs";
    if (f.epoch != (e.has("epoch") ? e.at("epoch").magnitude : 0)) return "epoch differs";
    if (f.dropped != (e.has("dropped") ? e.at("dropped").magnitude : 0)) return "dropped differs";
    const Json& bodies = e.at("bodies");
    if (f.bodies.size() != bodies.arr.size()) return "body count differs";
    for (size_t i = 0; i < f.bodies.size(); ++i) {
        const Body& b = f.bodies[i];
        const Json& eb = bodies.arr[i];
        std::string where = "body " + std::to_string(b.id) + ": ";
        if (b.id != eb.at("id").i64()) return where + "id differs";
        const Json& pos = eb.at("positions");
        const Json& conf = eb.at("confidence");
        size_t J = b.confidence.size();
        if (pos.arr.size() != J || conf.arr.size() != J) return where + "joint count differs";
        for (size_t j = 0; j < J; ++j) {
            const Json& p = pos.arr[j];
            if (p.type == Json::Null) {
                if (!std::isnan(b.positions[3 * j])) return where + "joint " + std::to_string(j) + " should be missing";
            } else {
                for (size_t k = 0; k < 3; ++k)
                    if (static_cast<double>(b.positions[3 * j + k]) != p.arr[k].num)
                        return where + "joint " + std::to_string(j) + " position differs";
            }
            if (static_cast<double>(b.confidence[j]) != conf.arr[j].num)
                return where + "joint " + std::to_string(j) + " confidence differs";
        }
        const Json& rec = eb.at("recovered");
        if ((rec.type == Json::Null) == b.has_recovered) return where + "presence of rec differs";
        if (b.has_recovered)
            for (size_t j = 0; j < J; ++j)
                if ((b.recovered[j] != 0) != rec.arr[j].b) return where + "recovered differs at joint " + std::to_string(j);
    }
    return "";
}

std::string compare_skeleton(const SkeletonMsg& s, const Json& e) {
    if (e.at("type").str != "skeleton") return "expected a frame, decoded a skeleton message";
    if (s.stream != e.at("stream").str || s.skeleton != e.at("skeleton").str) return "stream/skeleton differs";
    const Json& names = e.at("joint_names");
    if (names.arr.size() != s.joint_names.size()) return "joint count differs";
    for (size_t i = 0; i < names.arr.size(); ++i)
        if (names.arr[i].str != s.joint_names[i]) return "joint name " + std::to_string(i) + " differs";
    const Json& bones = e.at("bones");
    if (bones.arr.size() != s.bones.size()) return "bone count differs";
    for (size_t i = 0; i < s.bones.size(); ++i)
        if (bones.arr[i].arr[0].i64() != s.bones[i].first || bones.arr[i].arr[1].i64() != s.bones[i].second)
            return "bone " + std::to_string(i) + " differs";
    if (s.rate_hz != e.at("rate_hz").num) return "rate_hz differs";
    if (s.units != e.at("units").str) return "units differ";
    if (s.t_publish_ns != e.at("t_publish_ns").i64()) return "t_publish_ns differs";
    return "";
}

int check_vectors(const std::string& dir) {
    Json index = read_json(dir + "/index.json");
    Decoder dec;
    int failures = 0;
    size_t total = index.at("vectors").arr.size();
    for (const Json& name_j : index.at("vectors").arr) {
        const std::string& name = name_j.str;
        Json meta = read_json(dir + "/" + name + ".json");
        std::string payload = read_file(dir + "/" + name + ".bin");
        bool valid = meta.at("valid").b;
        msgpack_unpacked keep;
        msgpack_unpacked_init(&keep);
        std::string problem;
        try {
            std::string type = Decoder::unpack(payload, keep);
            if (type == "frame") {
                Frame f = dec.frame(keep.data);
                problem = valid ? compare_frame(f, meta.at("message")) : "invalid vector accepted";
            } else if (type == "skeleton") {
                SkeletonMsg s = dec.skeleton(keep.data);
                problem = valid ? compare_skeleton(s, meta.at("message")) : "invalid vector accepted";
            } else {
                throw Rejected("type", "unknown message type '" + type + "'");
            }
        } catch (const Rejected& r) {
            if (valid) problem = std::string("valid vector rejected (") + r.what() + ")";
            else if (r.reason != meta.at("reason").str) problem = "rejected for '" + r.reason + "', expected '" + meta.at("reason").str + "'";
            else std::printf("ok   %s: rejected (%s)\n", name.c_str(), r.what());
        }
        msgpack_unpacked_destroy(&keep);
        if (!problem.empty()) {
            std::printf("FAIL %s: %s\n", name.c_str(), problem.c_str());
            ++failures;
        } else if (valid) {
            std::printf("ok   %s\n", name.c_str());
        }
    }
    std::printf("%zu/%zu vectors ok\n", total - failures, total);
    return failures ? 1 : 0;
}

// ------------------------------------------------------------------ live subscriber

std::string recv_part(void* sock, bool& more) {
    zmq_msg_t msg;
    zmq_msg_init(&msg);
    if (zmq_msg_recv(&msg, sock, 0) < 0) {
        zmq_msg_close(&msg);
        throw std::runtime_error(std::string("zmq_msg_recv: ") + zmq_strerror(zmq_errno()));
    }
    std::string data(static_cast<const char*>(zmq_msg_data(&msg)), zmq_msg_size(&msg));
    more = zmq_msg_more(&msg);
    zmq_msg_close(&msg);
    return data;
}

int subscribe(const std::string& endpoint, std::vector<std::string> topics, long count, double timeout_s) {
    void* ctx = zmq_ctx_new();
    void* sock = zmq_socket(ctx, ZMQ_SUB);
    int linger = 0;
    zmq_setsockopt(sock, ZMQ_LINGER, &linger, sizeof linger);
    if (topics.empty()) topics.push_back("sf/");
    std::set<std::string> subs(topics.begin(), topics.end());
    subs.insert("sf/meta/");
    for (const auto& t : subs) zmq_setsockopt(sock, ZMQ_SUBSCRIBE, t.data(), t.size());
    if (zmq_connect(sock, endpoint.c_str()) != 0) {
        std::fprintf(stderr, "cannot connect to %s: %s\n", endpoint.c_str(), zmq_strerror(zmq_errno()));
        return 1;
    }
    Decoder dec;
    std::map<std::string, std::pair<uint64_t, uint64_t>> last_seq;  // topic -> (epoch, seq)
    long printed = 0, rejected = 0, gaps = 0, restarts = 0;
    auto start = std::chrono::steady_clock::now();
    int rc = 2;
    for (;;) {
        if (count >= 0 && printed >= count) { rc = 0; break; }
        double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        long wait_ms = 200;
        if (timeout_s >= 0) {
            if (elapsed >= timeout_s) break;
            wait_ms = std::min(200L, static_cast<long>((timeout_s - elapsed) * 1000) + 1);
        }
        zmq_pollitem_t item = {sock, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, wait_ms) <= 0) continue;
        std::vector<std::string> parts;
        bool more = true;
        while (more) parts.push_back(recv_part(sock, more));
        if (parts.size() != 2) {
            ++rejected;
            std::fprintf(stderr, "rejected: parts: %zu frames, expected 2\n", parts.size());
            continue;
        }
        const std::string& topic = parts[0];
        std::string kind, stream;
        size_t s1 = topic.find('/'), s2 = s1 == std::string::npos ? s1 : topic.find('/', s1 + 1);
        if (topic.compare(0, 3, "sf/") != 0 || s2 == std::string::npos) {
            ++rejected;
            std::fprintf(stderr, "rejected: topic: '%s'\n", topic.c_str());
            continue;
        }
        kind = topic.substr(s1 + 1, s2 - s1 - 1);
        stream = topic.substr(s2 + 1);
        if (!(kind == "raw" || kind == "live" || kind == "clean" || kind == "meta") || !valid_stream(stream)) {
            ++rejected;
            std::fprintf(stderr, "rejected: topic: '%s' is not sf/<raw|live|clean|meta>/<stream>\n", topic.c_str());
            continue;
        }
        msgpack_unpacked keep;
        msgpack_unpacked_init(&keep);
        try {
            std::string type = Decoder::unpack(parts[1], keep);
            if (type == "skeleton") {
                if (kind != "meta") throw Rejected("topic", "skeleton message on a frame topic");
                SkeletonMsg s = dec.skeleton(keep.data);
                if (s.stream != stream) throw Rejected("topic", "stream differs from topic");
                std::fprintf(stderr, "%s skeleton=%s joints=%zu bones=%zu rate_hz=%g\n", topic.c_str(),
                             s.skeleton.c_str(), s.joint_names.size(), s.bones.size(), s.rate_hz);
            } else if (type == "frame") {
                if (kind == "meta") throw Rejected("topic", "frame on a meta topic");
                Frame f = dec.frame(keep.data);
                if (f.stream != stream) throw Rejected("topic", "stream differs from topic");
                bool wanted = false;
                for (const auto& t : topics) wanted = wanted || topic.compare(0, t.size(), t) == 0;
                if (wanted) {
                    auto it = last_seq.find(topic);
                    if (it != last_seq.end() && it->second.first != f.epoch) ++restarts;  // new numbering
                    else if (it != last_seq.end() && f.seq != it->second.second + 1) ++gaps;
                    last_seq[topic] = {f.epoch, f.seq};
                    std::string line = topic + " seq=" + std::to_string(f.seq) + " t_sensor_ns=" +
                                       std::to_string(f.t_sensor_ns) + " bodies=" + std::to_string(f.bodies.size());
                    for (const Body& b : f.bodies) {
                        size_t missing = 0, rec = 0, J = b.confidence.size();
                        for (size_t j = 0; j < J; ++j) {
                            if (std::isnan(b.positions[3 * j])) ++missing;
                            else if (b.has_recovered && b.recovered[j]) ++rec;
                        }
                        line += " " + std::to_string(b.id) + ":" + std::to_string(J - missing - rec) + "/" +
                                std::to_string(rec) + "/" + std::to_string(missing);
                    }
                    if (f.filled) line += " filled";
                    if (f.dropped) line += " dropped=" + std::to_string(f.dropped);
                    std::printf("%s\n", line.c_str());
                    std::fflush(stdout);
                    ++printed;
                }
            } else {
                throw Rejected("type", "unknown message type '" + type + "' (ignored)");
            }
        } catch (const Rejected& r) {
            if (r.reason != "type") ++rejected;
            std::fprintf(stderr, "rejected on %s: %s\n", topic.c_str(), r.what());
        }
        msgpack_unpacked_destroy(&keep);
    }
    std::fprintf(stderr, "%ld frames, %ld rejected, %ld sequence gaps, %ld epoch changes\n", printed, rejected, gaps,
                 restarts);
    zmq_close(sock);
    zmq_ctx_term(ctx);
    return rc;
}

int usage() {
    std::fprintf(stderr,
                 "usage: subscriber --vectors DIR\n"
                 "       subscriber --connect ENDPOINT [--topic PREFIX]... [--count N] [--timeout S]\n");
    return 64;
}

}  // namespace

int main(int argc, char** argv) {
    std::string vectors, endpoint;
    std::vector<std::string> topics;
    long count = -1;
    double timeout_s = -1;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        if (i + 1 >= argc) return usage();
        std::string v = argv[++i];
        if (a == "--vectors") vectors = v;
        else if (a == "--connect") endpoint = v;
        else if (a == "--topic") topics.push_back(v);
        else if (a == "--count") count = std::atol(v.c_str());
        else if (a == "--timeout") timeout_s = std::atof(v.c_str());
        else return usage();
    }
    try {
        if (!vectors.empty()) return check_vectors(vectors);
        if (!endpoint.empty()) return subscribe(endpoint, topics, count, timeout_s);
    } catch (const std::exception& e) {
        std::fprintf(stderr, "error: %s\n", e.what());
        return 1;
    }
    return usage();
}
