// fastdds_peer: a Fast DDS 2.9 publisher/subscriber that Courier's interop
// tests run against Courier's own RTPS backend.
//
// Loopback only: the participant QoS is built here and nowhere else (no XML
// profiles, no environment): a single UDPv4 transport whitelisted to
// 127.0.0.1, no built-in transports (so no shared memory), metatraffic and
// user unicast locators on 127.0.0.1, no multicast locators, unicast SPDP to
// the initial peer 127.0.0.1. The profile/discovery-server environment
// variables Fast DDS would otherwise read are removed before Fast DDS starts.
//
// The two IDL types (types.idl) are written by hand as TopicDataType
// subclasses serialized with Fast CDR as plain CDR (XCDR1), as Fast DDS 2.9
// does; there is no fastddsgen here.
//
// Command line and output: see usage(); the
// same as cyclone_peer.c.
//
// Build (tests/peers.rs and sdk/tests/rtps_interop.rs do this; README.md
// beside this file documents it):
//   c++ -std=c++17 -O2 fastdds_peer.cpp -lfastrtps -lfastcdr -pthread

#include <atomic>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <poll.h>
#include <unistd.h>

#include <fastcdr/Cdr.h>
#include <fastcdr/FastBuffer.h>
#include <fastcdr/exceptions/Exception.h>
#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/common/InstanceHandle.hpp>
#include <fastdds/dds/domain/qos/DomainParticipantQos.hpp>
#include <fastdds/dds/log/Log.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/DataWriterListener.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/publisher/qos/DataWriterQos.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TopicDataType.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastdds/rtps/common/Locator.h>
#include <fastdds/rtps/common/SerializedPayload.h>
#include <fastdds/rtps/common/WriteParams.h>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>
#include <fastrtps/utils/md5.h>

namespace fdds = eprosima::fastdds::dds;
namespace frtps = eprosima::fastrtps::rtps;
namespace fcdr = eprosima::fastcdr;
using eprosima::fastrtps::types::ReturnCode_t;

namespace {

constexpr int EXIT_RUNTIME = 1;
constexpr int EXIT_TIMEOUT = 2;
constexpr int EXIT_ORPHANED = 3;
constexpr int EXIT_USAGE = 64;
constexpr long MAX_DOMAIN = 232; // 7400 + 250 * d + 61 must stay below 65536
constexpr const char* PROG = "fastdds_peer";

// ---- the two IDL types ----

struct Msg
{
    uint32_t seq = 0;
    std::string text;
    std::vector<uint8_t> payload;
};

struct Keyed
{
    int32_t id = 0;
    uint32_t seq = 0;
    std::string text;
};

struct StrKeyed
{
    std::string name;
    uint32_t seq = 0;
    std::string text;
};

// Size of plain CDR data, with alignment relative to the first byte after the
// 4-byte encapsulation header.
struct CdrSize
{
    size_t n = 0;

    void align(size_t a)
    {
        n = (n + a - 1) / a * a;
    }

    void u32()
    {
        align(4);
        n += 4;
    }

    void str(const std::string& s)
    {
        u32();
        n += s.size() + 1;
    }

    void octets(const std::vector<uint8_t>& v)
    {
        u32();
        n += v.size();
    }

    uint32_t total() const
    {
        // encapsulation header + body + up to 3 bytes of final padding
        return static_cast<uint32_t>(4 + n + 3);
    }
};

void begin_serialize(fcdr::Cdr& ser, frtps::SerializedPayload_t* payload)
{
    payload->encapsulation =
            ser.endianness() == fcdr::Cdr::BIG_ENDIANNESS ? CDR_BE : CDR_LE;
    ser.serialize_encapsulation();
}

void begin_deserialize(fcdr::Cdr& de, frtps::SerializedPayload_t* payload)
{
    de.read_encapsulation();
    payload->encapsulation =
            de.endianness() == fcdr::Cdr::BIG_ENDIANNESS ? CDR_BE : CDR_LE;
}

class MsgType : public fdds::TopicDataType
{
public:

    MsgType()
    {
        setName("courier::test::Msg");
        m_typeSize = 4 + 4 + 4 + 256 + 4 + 1024; // a first guess; payloads grow as needed
        m_isGetKeyDefined = false;
        auto_fill_type_object(false);
        auto_fill_type_information(false);
    }

    bool serialize(void* data, frtps::SerializedPayload_t* payload) override
    {
        const Msg* m = static_cast<const Msg*>(data);
        fcdr::FastBuffer buf(reinterpret_cast<char*>(payload->data), payload->max_size);
        fcdr::Cdr ser(buf, fcdr::Cdr::DEFAULT_ENDIAN, fcdr::Cdr::DDS_CDR);
        try
        {
            begin_serialize(ser, payload);
            ser.serialize(m->seq);
            ser.serialize(m->text);
            ser.serialize(m->payload);
        }
        catch (fcdr::exception::Exception& e)
        {
            std::fprintf(stderr, "%s: serialize Msg: %s\n", PROG, e.what());
            return false;
        }
        payload->length = static_cast<uint32_t>(ser.getSerializedDataLength());
        return true;
    }

    bool deserialize(frtps::SerializedPayload_t* payload, void* data) override
    {
        Msg* m = static_cast<Msg*>(data);
        fcdr::FastBuffer buf(reinterpret_cast<char*>(payload->data), payload->length);
        fcdr::Cdr de(buf, fcdr::Cdr::DEFAULT_ENDIAN, fcdr::Cdr::DDS_CDR);
        try
        {
            begin_deserialize(de, payload);
            de.deserialize(m->seq);
            de.deserialize(m->text);
            de.deserialize(m->payload);
        }
        catch (fcdr::exception::Exception& e)
        {
            std::fprintf(stderr, "%s: deserialize Msg (%u bytes): %s\n", PROG, payload->length,
                    e.what());
            return false;
        }
        return true;
    }

    std::function<uint32_t()> getSerializedSizeProvider(void* data) override
    {
        return [data]() -> uint32_t
               {
                   const Msg* m = static_cast<const Msg*>(data);
                   CdrSize s;
                   s.u32();
                   s.str(m->text);
                   s.octets(m->payload);
                   return s.total();
               };
    }

    void* createData() override
    {
        return new Msg();
    }

    void deleteData(void* data) override
    {
        delete static_cast<Msg*>(data);
    }

    bool getKey(void*, frtps::InstanceHandle_t*, bool) override
    {
        return false;
    }

};

class KeyedType : public fdds::TopicDataType
{
public:

    KeyedType()
    {
        setName("courier::test::Keyed");
        m_typeSize = 4 + 4 + 4 + 4 + 256;
        m_isGetKeyDefined = true;
        auto_fill_type_object(false);
        auto_fill_type_information(false);
    }

    bool serialize(void* data, frtps::SerializedPayload_t* payload) override
    {
        const Keyed* k = static_cast<const Keyed*>(data);
        fcdr::FastBuffer buf(reinterpret_cast<char*>(payload->data), payload->max_size);
        fcdr::Cdr ser(buf, fcdr::Cdr::DEFAULT_ENDIAN, fcdr::Cdr::DDS_CDR);
        try
        {
            begin_serialize(ser, payload);
            ser.serialize(k->id);
            ser.serialize(k->seq);
            ser.serialize(k->text);
        }
        catch (fcdr::exception::Exception& e)
        {
            std::fprintf(stderr, "%s: serialize Keyed: %s\n", PROG, e.what());
            return false;
        }
        payload->length = static_cast<uint32_t>(ser.getSerializedDataLength());
        return true;
    }

    // Also accepts a key-only payload (just `id`), which is what a dispose or
    // unregister DATA with a serialized key carries.
    bool deserialize(frtps::SerializedPayload_t* payload, void* data) override
    {
        Keyed* k = static_cast<Keyed*>(data);
        fcdr::FastBuffer buf(reinterpret_cast<char*>(payload->data), payload->length);
        fcdr::Cdr de(buf, fcdr::Cdr::DEFAULT_ENDIAN, fcdr::Cdr::DDS_CDR);
        try
        {
            begin_deserialize(de, payload);
            de.deserialize(k->id);
            k->seq = 0;
            k->text.clear();
            size_t used = static_cast<size_t>(de.getCurrentPosition() - de.getBufferPointer());
            if (used + 4 > payload->length)
            {
                return true; // key only (at most padding follows)
            }
            de.deserialize(k->seq);
            de.deserialize(k->text);
        }
        catch (fcdr::exception::Exception& e)
        {
            std::fprintf(stderr, "%s: deserialize Keyed (%u bytes): %s\n", PROG, payload->length,
                    e.what());
            return false;
        }
        return true;
    }

    std::function<uint32_t()> getSerializedSizeProvider(void* data) override
    {
        return [data]() -> uint32_t
               {
                   const Keyed* k = static_cast<const Keyed*>(data);
                   CdrSize s;
                   s.u32();
                   s.u32();
                   s.str(k->text);
                   return s.total();
               };
    }

    void* createData() override
    {
        return new Keyed();
    }

    void deleteData(void* data) override
    {
        delete static_cast<Keyed*>(data);
    }

    // The key hash (RTPS 9.6.3.8): the key members serialized as big-endian
    // CDR; the key's maximum serialized size (4 bytes for one int32) is not
    // over 16, so the hash is those bytes zero-padded to 16, unless MD5 is
    // forced (secure key), then MD5 of the same bytes.
    bool getKey(void* data, frtps::InstanceHandle_t* handle, bool force_md5) override
    {
        const Keyed* k = static_cast<const Keyed*>(data);
        unsigned char key[4];
        uint32_t u = static_cast<uint32_t>(k->id);
        key[0] = static_cast<unsigned char>(u >> 24);
        key[1] = static_cast<unsigned char>(u >> 16);
        key[2] = static_cast<unsigned char>(u >> 8);
        key[3] = static_cast<unsigned char>(u);
        if (force_md5)
        {
            MD5 md5;
            md5.init();
            md5.update(key, sizeof key);
            md5.finalize();
            for (size_t i = 0; i < 16; i++)
            {
                handle->value[i] = md5.digest[i];
            }
        }
        else
        {
            for (size_t i = 0; i < 16; i++)
            {
                handle->value[i] = i < sizeof key ? key[i] : 0;
            }
        }
        return true;
    }

};

// `courier::test::StrKeyed` (a string key): subscribers only.
class StrKeyedType : public fdds::TopicDataType
{
public:

    StrKeyedType()
    {
        setName("courier::test::StrKeyed");
        m_typeSize = 4 + 4 + 256 + 4 + 4 + 256;
        m_isGetKeyDefined = true;
        auto_fill_type_object(false);
        auto_fill_type_information(false);
    }

    bool serialize(void* data, frtps::SerializedPayload_t* payload) override
    {
        const StrKeyed* k = static_cast<const StrKeyed*>(data);
        fcdr::FastBuffer buf(reinterpret_cast<char*>(payload->data), payload->max_size);
        fcdr::Cdr ser(buf, fcdr::Cdr::DEFAULT_ENDIAN, fcdr::Cdr::DDS_CDR);
        try
        {
            begin_serialize(ser, payload);
            ser.serialize(k->name);
            ser.serialize(k->seq);
            ser.serialize(k->text);
        }
        catch (fcdr::exception::Exception& e)
        {
            std::fprintf(stderr, "%s: serialize StrKeyed: %s\n", PROG, e.what());
            return false;
        }
        payload->length = static_cast<uint32_t>(ser.getSerializedDataLength());
        return true;
    }

    // Also accepts a key-only payload (just `name`).
    bool deserialize(frtps::SerializedPayload_t* payload, void* data) override
    {
        StrKeyed* k = static_cast<StrKeyed*>(data);
        fcdr::FastBuffer buf(reinterpret_cast<char*>(payload->data), payload->length);
        fcdr::Cdr de(buf, fcdr::Cdr::DEFAULT_ENDIAN, fcdr::Cdr::DDS_CDR);
        try
        {
            begin_deserialize(de, payload);
            de.deserialize(k->name);
            k->seq = 0;
            k->text.clear();
            size_t used = static_cast<size_t>(de.getCurrentPosition() - de.getBufferPointer());
            if (used + 4 > payload->length)
            {
                return true; // key only (at most padding follows)
            }
            de.deserialize(k->seq);
            de.deserialize(k->text);
        }
        catch (fcdr::exception::Exception& e)
        {
            std::fprintf(stderr, "%s: deserialize StrKeyed (%u bytes): %s\n", PROG,
                    payload->length, e.what());
            return false;
        }
        return true;
    }

    std::function<uint32_t()> getSerializedSizeProvider(void* data) override
    {
        return [data]() -> uint32_t
               {
                   const StrKeyed* k = static_cast<const StrKeyed*>(data);
                   CdrSize s;
                   s.str(k->name);
                   s.u32();
                   s.str(k->text);
                   return s.total();
               };
    }

    void* createData() override
    {
        return new StrKeyed();
    }

    void deleteData(void* data) override
    {
        delete static_cast<StrKeyed*>(data);
    }

    // The key hash (RTPS 9.6.3.8): an unbounded string key can exceed 16
    // bytes, so it is always the MD5 of the key serialized as big-endian
    // CDR (length with the NUL, the bytes, the NUL), as fastddsgen's code does.
    bool getKey(void* data, frtps::InstanceHandle_t* handle, bool) override
    {
        const StrKeyed* k = static_cast<const StrKeyed*>(data);
        std::vector<unsigned char> key;
        uint32_t n = static_cast<uint32_t>(k->name.size() + 1);
        key.push_back(static_cast<unsigned char>(n >> 24));
        key.push_back(static_cast<unsigned char>(n >> 16));
        key.push_back(static_cast<unsigned char>(n >> 8));
        key.push_back(static_cast<unsigned char>(n));
        key.insert(key.end(), k->name.begin(), k->name.end());
        key.push_back(0);
        MD5 md5;
        md5.init();
        md5.update(key.data(), static_cast<unsigned int>(key.size()));
        md5.finalize();
        for (size_t i = 0; i < 16; i++)
        {
            handle->value[i] = md5.digest[i];
        }
        return true;
    }

};

// ---- options ----

enum class Kind { None, Msg, Keyed, StrKeyed };

struct Options
{
    long domain = -1;
    std::string topic;
    Kind type = Kind::None;
    int role = 0;        // 1 pub, 2 sub, 3 serve, 4 request
    int reliability = 0; // 1 reliable, 2 best effort
    bool transient_local = false;
    long depth = 10;
    bool depth_set = false;
    bool keep_all = false;
    long count = 0;
    bool count_set = false;
    std::vector<long> sizes;
    long period_ms = 0;
    long dispose_every = 0;
    long wait_match = 0;
    bool wait_stdin = false;
    long timeout_s = 60;
    long linger_ms = 0;
    long settle_ms = 250;
    bool settle_set = false;
    long keys = 0;
    long disposed = 0;
    bool disposed_set = false;
    bool autodispose = true;
    bool hb_piggyback = true;
    bool strict_instances = false;
    std::string text;
    bool text_set = false;
    std::string trace;
    // --liveliness KIND:SECONDS: 0 none (Fast DDS's default, AUTOMATIC and
    // infinite), 1 automatic, 2 manual by participant, 3 manual by topic
    int liveliness = 0;
    double liveliness_s = 0;
    long assert_ms = 0;    // --assert-ms (writers): assert_liveliness period
    long assert_for_s = 0; // --assert-for-s: stop asserting after this long
    long run_s = 0;        // --run-s (readers without --count/--disposed)
};

void usage(FILE* out)
{
    std::fprintf(out,
            "usage: %s --domain N --topic NAME --type msg|keyed --pub|--sub|--serve|--request\n"
            "          --reliable|--best-effort [--transient-local]\n"
            "          [--depth N (keep last, default 10) | --keep-all] [--count N]\n"
            "          [--size BYTES[,BYTES...]] [--period-ms N] [--dispose-every N]\n"
            "          [--wait-match N] [--wait-stdin] [--settle-ms N] [--timeout-s N] [--linger-ms N]\n"
            "          [--keys N] [--disposed N] [--no-autodispose] [--no-hb-piggyback]\n"
            "          [--text PREFIX] [--trace FILE] [--strict-instances]\n"
            "          [--liveliness automatic|participant|topic[:SECONDS]] [--run-s N]\n"
            "          [--assert-ms N [--assert-for-s N]]\n"
            "--type strkeyed (subscribers): courier::test::StrKeyed, a string key.\n"
            "--strict-instances: a dispose or unregister of an instance never seen alive\n"
            "  is reported as disposed-unknown/unregistered-unknown <instance handle>,\n"
            "  not decoded from the handle.\n"
            "--liveliness KIND:SECONDS (default 1 s): the writer offers, the reader requests\n"
            "  LIVELINESS of KIND (automatic, participant = manual by participant, topic =\n"
            "  manual by topic) with that lease. A reader then prints\n"
            "  liveliness <alive_count> <not_alive_count> whenever its liveliness-changed\n"
            "  counts change, a writer liveliness-lost <total> on each loss.\n"
            "--assert-ms N (writers, manual kinds): while it lingers (--linger-ms), the\n"
            "  writer calls assert_liveliness every N ms without writing; --assert-for-s S\n"
            "  stops that S seconds after it began (it lingers on without asserting).\n"
            "--run-s N (subscribers without --count/--disposed): done after N seconds.\n"
            "The participant lease (SPDP) is 20 s, Fast DDS's default: a writer stopped\n"
            "  (SIGSTOP) for less loses its liveliness, not its participant.\n"
            "Loopback only (UDPv4 on 127.0.0.1, unicast discovery, no shared memory).\n"
            "A subscriber is done after --count samples and --disposed disposals (both when\n"
            "given, otherwise after --run-s or at --timeout-s); either role then stays\n"
            "--linger-ms.\n"
            "Output lines: ready | matched <n> | sent <seq> | sent <id> <seq> | dispose <id>\n"
            "  | acked | sample <seq> <text> <len> <fnv1a32> | sample <id> <seq> <text>\n"
            "  | disposed <id> | unregistered <id> | done | timeout\n"
            "  | liveliness <alive> <not_alive> | liveliness-lost <total> (--liveliness)\n"
            "  | asserted (--assert-for-s: the writer stopped asserting)\n"
            "  | request <seq> <text> (--serve) | reply <seq> <text> related|unrelated (--request)\n"
            "--serve/--request: a ROS 2-style service on rq/NAMERequest and rr/NAMEReply\n"
            "  (type msg); --serve answers --count requests, --request sends --count.\n"
            "Exit: 0 done, 1 DDS error, 2 timeout, 3 parent gone, 64 usage.\n",
            PROG);
}

[[noreturn]] void usage_error(const char* fmt, ...)
{
    va_list ap;
    std::fprintf(stderr, "%s: usage error: ", PROG);
    va_start(ap, fmt);
    std::vfprintf(stderr, fmt, ap);
    va_end(ap);
    std::fputc('\n', stderr);
    usage(stderr);
    std::exit(EXIT_USAGE);
}

[[noreturn]] void fail(const std::string& what)
{
    fdds::Log::Flush();
    std::fprintf(stderr, "%s: error: %s\n", PROG, what.c_str());
    std::fflush(stdout);
    std::_Exit(EXIT_RUNTIME);
}

std::mutex out_mutex;

void emit(const char* fmt, ...)
{
    std::lock_guard<std::mutex> lock(out_mutex);
    va_list ap;
    va_start(ap, fmt);
    std::vfprintf(stdout, fmt, ap);
    va_end(ap);
    std::fputc('\n', stdout);
    std::fflush(stdout);
}

long parse_num(const char* flag, const char* arg, long min, long max)
{
    if (arg == nullptr)
    {
        usage_error("%s needs a value", flag);
    }
    char* end = nullptr;
    errno = 0;
    long v = std::strtol(arg, &end, 10);
    if (errno != 0 || end == arg || *end != '\0' || v < min || v > max)
    {
        usage_error("%s: '%s' is not an integer in %ld..%ld", flag, arg, min, max);
    }
    return v;
}

void parse_sizes(Options& o, const char* arg)
{
    if (arg == nullptr)
    {
        usage_error("--size needs a value");
    }
    std::string s(arg);
    o.sizes.clear();
    size_t pos = 0;
    for (;;)
    {
        size_t comma = s.find(',', pos);
        std::string item = s.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
        if (item.empty() || o.sizes.size() == 64)
        {
            usage_error("--size: bad list '%s'", arg);
        }
        o.sizes.push_back(parse_num("--size", item.c_str(), 0, 64L * 1024 * 1024));
        if (comma == std::string::npos)
        {
            break;
        }
        pos = comma + 1;
    }
}

Options parse_args(int argc, char** argv)
{
    Options o;
    for (int i = 1; i < argc; i++)
    {
        std::string a = argv[i];
        const char* v = (i + 1 < argc) ? argv[i + 1] : nullptr;
        auto value = [&]() -> const char*
                {
                    i++;
                    return v;
                };
        if (a == "--help" || a == "-h")
        {
            usage(stdout);
            std::exit(0);
        }
        else if (a == "--domain")
        {
            o.domain = parse_num("--domain", value(), 0, MAX_DOMAIN);
        }
        else if (a == "--topic")
        {
            const char* t = value();
            if (t == nullptr || *t == '\0')
            {
                usage_error("--topic needs a non-empty name");
            }
            o.topic = t;
        }
        else if (a == "--type")
        {
            const char* t = value();
            if (t == nullptr)
            {
                usage_error("--type needs a value");
            }
            if (std::strcmp(t, "msg") == 0)
            {
                o.type = Kind::Msg;
            }
            else if (std::strcmp(t, "keyed") == 0)
            {
                o.type = Kind::Keyed;
            }
            else if (std::strcmp(t, "strkeyed") == 0)
            {
                o.type = Kind::StrKeyed;
            }
            else
            {
                usage_error("--type must be msg, keyed or strkeyed, not '%s'", t);
            }
        }
        else if (a == "--pub" || a == "--sub" || a == "--serve" || a == "--request")
        {
            int r = a == "--pub" ? 1 : a == "--sub" ? 2 : a == "--serve" ? 3 : 4;
            if (o.role != 0 && o.role != r)
            {
                usage_error("--pub, --sub, --serve and --request are exclusive");
            }
            o.role = r;
        }
        else if (a == "--reliable" || a == "--best-effort")
        {
            int r = a == "--reliable" ? 1 : 2;
            if (o.reliability != 0 && o.reliability != r)
            {
                usage_error("--reliable and --best-effort are exclusive");
            }
            o.reliability = r;
        }
        else if (a == "--transient-local")
        {
            o.transient_local = true;
        }
        else if (a == "--depth")
        {
            o.depth = parse_num("--depth", value(), 1, 100000);
            o.depth_set = true;
        }
        else if (a == "--keep-all")
        {
            o.keep_all = true;
        }
        else if (a == "--count")
        {
            o.count = parse_num("--count", value(), 0, INT32_MAX);
            o.count_set = true;
        }
        else if (a == "--size")
        {
            parse_sizes(o, value());
        }
        else if (a == "--period-ms")
        {
            o.period_ms = parse_num("--period-ms", value(), 0, 3600000);
        }
        else if (a == "--dispose-every")
        {
            o.dispose_every = parse_num("--dispose-every", value(), 1, INT32_MAX);
        }
        else if (a == "--wait-match")
        {
            o.wait_match = parse_num("--wait-match", value(), 0, 1000);
        }
        else if (a == "--wait-stdin")
        {
            o.wait_stdin = true;
        }
        else if (a == "--settle-ms")
        {
            o.settle_ms = parse_num("--settle-ms", value(), 0, 3600000);
            o.settle_set = true;
        }
        else if (a == "--timeout-s")
        {
            o.timeout_s = parse_num("--timeout-s", value(), 1, 86400);
        }
        else if (a == "--linger-ms")
        {
            o.linger_ms = parse_num("--linger-ms", value(), 0, 3600000);
        }
        else if (a == "--keys")
        {
            o.keys = parse_num("--keys", value(), 1, INT32_MAX);
        }
        else if (a == "--disposed")
        {
            o.disposed = parse_num("--disposed", value(), 0, INT32_MAX);
            o.disposed_set = true;
        }
        else if (a == "--no-autodispose")
        {
            o.autodispose = false;
        }
        else if (a == "--no-hb-piggyback")
        {
            o.hb_piggyback = false;
        }
        else if (a == "--strict-instances")
        {
            o.strict_instances = true;
        }
        else if (a == "--text")
        {
            const char* t = value();
            if (t == nullptr)
            {
                usage_error("--text needs a value");
            }
            o.text = t;
            o.text_set = true;
        }
        else if (a == "--liveliness")
        {
            const char* t = value();
            if (t == nullptr)
            {
                usage_error("--liveliness needs a value");
            }
            std::string spec(t);
            size_t colon = spec.find(':');
            std::string kind = spec.substr(0, colon);
            if (kind == "automatic")
            {
                o.liveliness = 1;
            }
            else if (kind == "participant")
            {
                o.liveliness = 2;
            }
            else if (kind == "topic")
            {
                o.liveliness = 3;
            }
            else
            {
                usage_error("--liveliness kind must be automatic, participant or topic, not '%s'",
                        kind.c_str());
            }
            o.liveliness_s = 1;
            if (colon != std::string::npos)
            {
                std::string secs = spec.substr(colon + 1);
                char* end = nullptr;
                errno = 0;
                double d = std::strtod(secs.c_str(), &end);
                if (secs.empty() || errno != 0 || *end != '\0' || !(d >= 0.001) || d > 86400)
                {
                    usage_error("--liveliness: lease '%s' is not a number of seconds in 0.001..86400",
                            secs.c_str());
                }
                o.liveliness_s = d;
            }
        }
        else if (a == "--assert-ms")
        {
            o.assert_ms = parse_num("--assert-ms", value(), 1, 3600000);
        }
        else if (a == "--assert-for-s")
        {
            o.assert_for_s = parse_num("--assert-for-s", value(), 1, 86400);
        }
        else if (a == "--run-s")
        {
            o.run_s = parse_num("--run-s", value(), 1, 86400);
        }
        else if (a == "--trace")
        {
            const char* t = value();
            if (t == nullptr || *t == '\0')
            {
                usage_error("--trace needs a file name");
            }
            o.trace = t;
        }
        else
        {
            usage_error("unknown argument '%s'", a.c_str());
        }
    }
    if (o.domain < 0)
    {
        usage_error("--domain is required");
    }
    if (o.topic.empty())
    {
        usage_error("--topic is required");
    }
    if (o.type == Kind::None)
    {
        usage_error("--type is required");
    }
    if (o.role == 0)
    {
        usage_error("one of --pub, --sub, --serve or --request is required");
    }
    if (o.role >= 3 && o.type != Kind::Msg)
    {
        usage_error("--serve and --request take --type msg");
    }
    if (o.reliability == 0)
    {
        usage_error("one of --reliable or --best-effort is required");
    }
    if (o.keep_all && o.depth_set)
    {
        usage_error("--depth and --keep-all are exclusive");
    }
    if (o.role == 2)
    {
        if (!o.sizes.empty() || o.period_ms || o.dispose_every || o.wait_match || o.wait_stdin ||
                o.settle_set || o.keys || o.text_set || !o.autodispose || !o.hb_piggyback)
        {
            usage_error("--size, --period-ms, --dispose-every, --wait-match, --wait-stdin, "
                    "--settle-ms, --keys, --no-autodispose, --no-hb-piggyback and --text are "
                    "publisher options");
        }
        if (o.disposed_set && o.type == Kind::Msg)
        {
            usage_error("--disposed is for --type keyed or strkeyed");
        }
        if (o.assert_ms || o.assert_for_s)
        {
            usage_error("--assert-ms and --assert-for-s are publisher options");
        }
        if (o.run_s && (o.count_set || o.disposed_set))
        {
            usage_error("--run-s is for a subscriber without --count and --disposed");
        }
    }
    else
    {
        if (o.type == Kind::StrKeyed)
        {
            usage_error("--type strkeyed is for subscribers");
        }
        if (o.strict_instances)
        {
            usage_error("--strict-instances is a subscriber option");
        }
        if (o.disposed_set)
        {
            usage_error("--disposed is a subscriber option");
        }
        if (o.run_s)
        {
            usage_error("--run-s is a subscriber option");
        }
        if (o.role != 1 && (o.liveliness || o.assert_ms || o.assert_for_s))
        {
            usage_error("--liveliness, --assert-ms and --assert-for-s are for --pub or --sub");
        }
        if (o.assert_ms && o.liveliness != 2 && o.liveliness != 3)
        {
            usage_error("--assert-ms needs --liveliness participant or topic");
        }
        if (o.assert_for_s && !o.assert_ms)
        {
            usage_error("--assert-for-s needs --assert-ms");
        }
        if (!o.count_set)
        {
            o.count = 1;
        }
    }
    if (o.type != Kind::Msg && !o.sizes.empty())
    {
        usage_error("--size is for --type msg");
    }
    if (o.type == Kind::Msg && (o.dispose_every || o.keys || !o.autodispose))
    {
        usage_error("--dispose-every, --keys and --no-autodispose are for --type keyed");
    }
    if (o.sizes.empty())
    {
        o.sizes.push_back(0);
    }
    if (!o.text_set)
    {
        o.text = "fastdds";
    }
    return o;
}

// ---- time and lifetime ----

const auto start_time = std::chrono::steady_clock::now();
pid_t initial_ppid;
long timeout_ms_total;

int64_t elapsed_ms()
{
    return std::chrono::duration_cast<std::chrono::milliseconds>(
        std::chrono::steady_clock::now() - start_time).count();
}

// Milliseconds left before --timeout-s; exits with 2 when none are left and
// with 3 when the parent process has gone.
int64_t remaining_ms()
{
    if (getppid() != initial_ppid)
    {
        std::fprintf(stderr, "%s: parent process gone, exiting\n", PROG);
        std::_Exit(EXIT_ORPHANED);
    }
    int64_t left = timeout_ms_total - elapsed_ms();
    if (left <= 0)
    {
        emit("timeout");
        std::_Exit(EXIT_TIMEOUT);
    }
    return left;
}

// Wakes the main loop from Fast DDS's listener threads.
struct Wakeup
{
    std::mutex m;
    std::condition_variable cv;
    bool flag = false;

    void notify()
    {
        {
            std::lock_guard<std::mutex> lock(m);
            flag = true;
        }
        cv.notify_all();
    }

    // Waits for a notification, at most `ms` (bounded by 50 ms and the timeout).
    void wait(int64_t ms)
    {
        int64_t left = remaining_ms();
        if (ms > left)
        {
            ms = left;
        }
        if (ms > 50)
        {
            ms = 50;
        }
        std::unique_lock<std::mutex> lock(m);
        cv.wait_for(lock, std::chrono::milliseconds(ms), [this]
                {
                    return flag;
                });
        flag = false;
    }

};

Wakeup wakeup;

class WriterListener : public fdds::DataWriterListener
{
public:

    void on_publication_matched(fdds::DataWriter*, const fdds::PublicationMatchedStatus&) override
    {
        wakeup.notify();
    }

    // Only with --liveliness (the status mask): a manual writer that asserted
    // nothing within its lease.
    void on_liveliness_lost(fdds::DataWriter*, const fdds::LivelinessLostStatus& st) override
    {
        emit("liveliness-lost %d", st.total_count);
    }

};

class ReaderListener : public fdds::DataReaderListener
{
public:

    void on_data_available(fdds::DataReader*) override
    {
        wakeup.notify();
    }

    void on_subscription_matched(fdds::DataReader*, const fdds::SubscriptionMatchedStatus&) override
    {
        wakeup.notify();
    }

    // Only with --liveliness (the status mask): the counts, when they change.
    void on_liveliness_changed(fdds::DataReader*, const fdds::LivelinessChangedStatus& st) override
    {
        std::lock_guard<std::mutex> lock(m);
        if (st.alive_count != alive || st.not_alive_count != not_alive)
        {
            alive = st.alive_count;
            not_alive = st.not_alive_count;
            emit("liveliness %d %d", alive, not_alive);
        }
        wakeup.notify();
    }

private:

    std::mutex m;
    int32_t alive = 0;
    int32_t not_alive = 0;
};

void sleep_ms(int64_t ms)
{
    int64_t until = elapsed_ms() + ms;
    while (elapsed_ms() < until)
    {
        int64_t left = until - elapsed_ms();
        std::this_thread::sleep_for(std::chrono::milliseconds(std::min<int64_t>(
                    std::min<int64_t>(left, 50), remaining_ms())));
    }
    (void)remaining_ms();
}

// ---- payload and output helpers ----

uint8_t payload_byte(size_t i, uint32_t seq)
{
    return static_cast<uint8_t>((i * 7u + seq) & 0xffu);
}

uint32_t fnv1a32(const std::vector<uint8_t>& v)
{
    uint32_t h = 0x811c9dc5u;
    for (uint8_t b : v)
    {
        h ^= b;
        h *= 0x01000193u;
    }
    return h;
}

// Text as one whitespace-free token: bytes outside 0x21..0x7e and the
// characters % and " become %XX; the empty string is printed as "".
std::string escape_text(const std::string& s)
{
    if (s.empty())
    {
        return "\"\"";
    }
    std::string out;
    char hex[4];
    for (unsigned char c : s)
    {
        if (c <= 0x20 || c >= 0x7f || c == '%' || c == '"')
        {
            std::snprintf(hex, sizeof hex, "%%%02X", c);
            out += hex;
        }
        else
        {
            out += static_cast<char>(c);
        }
    }
    return out;
}

std::string rc_name(const ReturnCode_t& rc)
{
    return "return code " + std::to_string(rc());
}

// ---- DDS setup ----

// Fast DDS's log on stderr as plain lines (its own consumers add colours).
class StderrLog : public fdds::LogConsumer
{
public:

    void Consume(const fdds::Log::Entry& e) override
    {
        const char* kind = e.kind == fdds::Log::Kind::Error ? "error" :
                e.kind == fdds::Log::Kind::Warning ? "warning" : "info";
        std::fprintf(stderr, "%s: fastdds %s [%s] %s\n", PROG, kind,
                e.context.category ? e.context.category : "", e.message.c_str());
    }

};

void quiet_environment()
{
    // Anything that could give Fast DDS another configuration.
    static const char* vars[] = {
        "FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE", "ROS_DISCOVERY_SERVER",
        "FASTDDS_ENVIRONMENT_FILE", "FASTDDS_STATISTICS",
    };
    for (const char* v : vars)
    {
        unsetenv(v);
    }
    // and no DEFAULT_FASTRTPS_PROFILES.xml from the working directory
    setenv("SKIP_DEFAULT_XML_FILE", "1", 1);
}

fdds::DomainParticipantQos loopback_participant_qos()
{
    fdds::DomainParticipantQos qos; // built from scratch: no XML profile involved
    qos.name("courier-fastdds-peer");

    auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
    udp->interfaceWhiteList.clear();
    udp->interfaceWhiteList.emplace_back("127.0.0.1");
    // SPDP goes to the metatraffic ports of participant indices 0..range-1 on
    // 127.0.0.1; Cyclone's config allows indices up to 20.
    udp->maxInitialPeersRange = 21;
    qos.transport().user_transports.clear();
    qos.transport().user_transports.push_back(udp);
    qos.transport().use_builtin_transports = false; // no SHM, no default UDP

    frtps::Locator_t lo;
    lo.kind = LOCATOR_KIND_UDPv4;
    lo.port = 0; // 0: the well-known port for this domain and participant index
    frtps::IPLocator::setIPv4(lo, 127, 0, 0, 1);

    auto& wire = qos.wire_protocol();
    wire.builtin.discovery_config.discoveryProtocol = frtps::DiscoveryProtocol_t::SIMPLE;
    // Fast DDS's default participant lease, said here: the liveliness tests
    // stop this process for a few seconds and expect its participant to stay
    wire.builtin.discovery_config.leaseDuration = eprosima::fastrtps::Duration_t(20, 0);
    wire.builtin.metatrafficUnicastLocatorList.clear();
    wire.builtin.metatrafficUnicastLocatorList.push_back(lo);
    wire.builtin.metatrafficMulticastLocatorList.clear();
    wire.builtin.initialPeersList.clear();
    wire.builtin.initialPeersList.push_back(lo);
    wire.default_unicast_locator_list.clear();
    wire.default_unicast_locator_list.push_back(lo);
    wire.default_multicast_locator_list.clear();
    return qos;
}

template<typename Q>
void apply_endpoint_qos(Q& q, const Options& o)
{
    q.reliability().kind = o.reliability == 1 ? fdds::RELIABLE_RELIABILITY_QOS :
            fdds::BEST_EFFORT_RELIABILITY_QOS;
    q.reliability().max_blocking_time = eprosima::fastrtps::Duration_t(1, 0);
    q.durability().kind = o.transient_local ? fdds::TRANSIENT_LOCAL_DURABILITY_QOS :
            fdds::VOLATILE_DURABILITY_QOS;
    q.history().kind = o.keep_all ? fdds::KEEP_ALL_HISTORY_QOS : fdds::KEEP_LAST_HISTORY_QOS;
    q.history().depth = o.keep_all ? 1 : static_cast<int32_t>(o.depth);
    // Room for deep histories and many instances.
    // (Fast DDS requires max_samples >= max_instances * max_samples_per_instance.)
    auto& rl = q.resource_limits();
    rl.max_instances = 1000;
    rl.max_samples_per_instance = std::max<int32_t>(1000, static_cast<int32_t>(o.depth));
    rl.max_samples = rl.max_instances * rl.max_samples_per_instance;
    rl.allocated_samples = 100;
    if (o.liveliness)
    {
        q.liveliness().kind = o.liveliness == 1 ? fdds::AUTOMATIC_LIVELINESS_QOS :
                o.liveliness == 2 ? fdds::MANUAL_BY_PARTICIPANT_LIVELINESS_QOS :
                fdds::MANUAL_BY_TOPIC_LIVELINESS_QOS;
        q.liveliness().lease_duration = eprosima::fastrtps::Duration_t(
            static_cast<long double>(o.liveliness_s));
    }
}

// Reliable writers announce their history every 100 ms instead of Fast DDS's
// default 3 s, so a lost fragment of a large sample (a burst of 200 KiB
// overflows the default socket buffer) is repaired in a tenth of a second
// instead of stalling the test for 3.
void apply_writer_qos(fdds::DataWriterQos& q, const Options& o)
{
    apply_endpoint_qos(q, o);
    q.reliable_writer_qos().times.heartbeatPeriod = eprosima::fastrtps::Duration_t(0, 100000000);
    // --no-hb-piggyback: heartbeats only every 100 ms, none inside a burst of
    // data. A Cyclone DDS 0.10 volatile reader takes the last sequence number
    // of the first heartbeat it processes as its starting point and drops
    // older data; Fast DDS's one heartbeat at match time can reach it before
    // it knows this writer (and is ignored), so the first one it processes
    // may be a piggybacked one in the middle of sample 1's fragments, and
    // sample 1 is lost.
    q.reliable_writer_qos().disable_heartbeat_piggyback = !o.hb_piggyback;
    // Fast DDS's participant messages for AUTOMATIC (and MANUAL_BY_PARTICIPANT)
    // writers go out every announcement_period, infinite by default: none at
    // all. A third of the lease, as Courier and Cyclone DDS do.
    if (o.liveliness)
    {
        q.liveliness().announcement_period = eprosima::fastrtps::Duration_t(
            static_cast<long double>(o.liveliness_s / 3));
    }
}

int32_t last_matched = 0;

void report_matched(int32_t cur)
{
    if (cur != last_matched)
    {
        last_matched = cur;
        emit("matched %d", cur);
    }
}

void check_matched(fdds::DataWriter* w)
{
    fdds::PublicationMatchedStatus st;
    ReturnCode_t rc = w->get_publication_matched_status(st);
    if (rc != ReturnCode_t::RETCODE_OK)
    {
        fail("get_publication_matched_status: " + rc_name(rc));
    }
    report_matched(st.current_count);
}

void check_matched(fdds::DataReader* r)
{
    fdds::SubscriptionMatchedStatus st;
    ReturnCode_t rc = r->get_subscription_matched_status(st);
    if (rc != ReturnCode_t::RETCODE_OK)
    {
        fail("get_subscription_matched_status: " + rc_name(rc));
    }
    report_matched(st.current_count);
}

void write_retrying(fdds::DataWriter* w, void* sample)
{
    for (;;)
    {
        ReturnCode_t rc = w->write(sample, fdds::HANDLE_NIL);
        if (rc == ReturnCode_t::RETCODE_OK)
        {
            return;
        }
        if (rc != ReturnCode_t::RETCODE_TIMEOUT && rc != ReturnCode_t::RETCODE_OUT_OF_RESOURCES)
        {
            fail("write: " + rc_name(rc));
        }
        (void)remaining_ms(); // history full (keep-all): again until --timeout-s
    }
}

// --wait-stdin: waits for a line on standard input, the test's signal that
// the subscriber has matched too (a writer matching a reader does not mean
// the reader knows the writer yet). End of input before it is an error.
void wait_stdin_line()
{
    for (;;)
    {
        struct pollfd p = {};
        p.fd = STDIN_FILENO;
        p.events = POLLIN;
        int64_t left = remaining_ms();
        int r = poll(&p, 1, static_cast<int>(std::min<int64_t>(left, 50)));
        if (r < 0 && errno != EINTR)
        {
            fail(std::string("poll stdin: ") + std::strerror(errno));
        }
        if (r > 0)
        {
            char c;
            ssize_t n = read(STDIN_FILENO, &c, 1);
            if (n == 0)
            {
                fail("--wait-stdin: standard input ended before a line");
            }
            if (n < 0 && errno != EINTR && errno != EAGAIN)
            {
                fail(std::string("read stdin: ") + std::strerror(errno));
            }
            if (n == 1 && c == '\n')
            {
                return;
            }
        }
    }
}

void run_pub(const Options& o, fdds::DataWriter* w)
{
    if (o.wait_match > 0)
    {
        while (last_matched < o.wait_match)
        {
            wakeup.wait(50);
            check_matched(w);
        }
    }
    if (o.wait_stdin)
    {
        wait_stdin_line();
    }
    if (o.wait_match > 0)
    {
        sleep_ms(o.settle_ms);
    }

    Msg m;
    Keyed k;
    for (long n = 1; n <= o.count; n++)
    {
        uint32_t seq = static_cast<uint32_t>(n);
        (void)remaining_ms();
        check_matched(w);
        std::string text = o.text + "-" + std::to_string(seq);
        if (o.type == Kind::Msg)
        {
            size_t size = static_cast<size_t>(o.sizes[static_cast<size_t>(n - 1) % o.sizes.size()]);
            m.seq = seq;
            m.text = text;
            m.payload.resize(size);
            for (size_t i = 0; i < size; i++)
            {
                m.payload[i] = payload_byte(i, seq);
            }
            write_retrying(w, &m);
            emit("sent %u", seq);
        }
        else
        {
            k.id = o.keys ? static_cast<int32_t>(n % o.keys) : static_cast<int32_t>(n);
            k.seq = seq;
            k.text = text;
            write_retrying(w, &k);
            emit("sent %d %u", k.id, seq);
            if (o.dispose_every && n % o.dispose_every == 0)
            {
                ReturnCode_t rc = w->dispose(&k, fdds::HANDLE_NIL);
                if (rc != ReturnCode_t::RETCODE_OK)
                {
                    fail("dispose: " + rc_name(rc));
                }
                emit("dispose %d", k.id);
            }
        }
        if (o.period_ms && n < o.count)
        {
            sleep_ms(o.period_ms);
        }
    }

    if (o.reliability == 1 && o.count > 0)
    {
        for (;;)
        {
            int64_t left = remaining_ms();
            int64_t step = std::min<int64_t>(left, 100);
            ReturnCode_t rc = w->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(
                        0, static_cast<uint32_t>(step * 1000000)));
            if (rc == ReturnCode_t::RETCODE_OK)
            {
                emit("acked");
                break;
            }
            // Fast DDS 2.9 reports a timeout here as RETCODE_ERROR, not
            // RETCODE_TIMEOUT: both mean "not yet"; --timeout-s bounds the loop
            if (rc != ReturnCode_t::RETCODE_TIMEOUT && rc != ReturnCode_t::RETCODE_ERROR)
            {
                fail("wait_for_acknowledgments: " + rc_name(rc));
            }
            check_matched(w);
        }
    }
    if (o.linger_ms)
    {
        // --assert-ms: assert_liveliness (no data) every assert_ms, for
        // --assert-for-s when given
        int64_t now = elapsed_ms();
        int64_t until = now + o.linger_ms;
        int64_t assert_until = o.assert_for_s ? now + o.assert_for_s * 1000 : until;
        int64_t next_assert = now;
        bool asserting = o.assert_ms > 0;
        while (elapsed_ms() < until)
        {
            now = elapsed_ms();
            if (asserting && now >= assert_until)
            {
                asserting = false;
                emit("asserted");
            }
            if (asserting && now >= next_assert)
            {
                ReturnCode_t rc = w->assert_liveliness();
                if (rc != ReturnCode_t::RETCODE_OK)
                {
                    fail("assert_liveliness: " + rc_name(rc));
                }
                next_assert = now + o.assert_ms;
            }
            int64_t wake = asserting ? std::min(until, std::min(next_assert, assert_until)) : until;
            wakeup.wait(std::max<int64_t>(1, wake - elapsed_ms()));
            check_matched(w);
        }
    }
    emit("done");
}

// Reports a disposed/unregistered instance once per transition out of ALIVE.
struct InstanceTracker
{
    std::map<frtps::InstanceHandle_t, int32_t> ids;
    std::map<int32_t, fdds::InstanceStateKind> states;
    bool noted_serialized_key = false;

    void learn(const frtps::InstanceHandle_t& h, int32_t id)
    {
        ids[h] = id;
    }

    static int32_t be32(const frtps::InstanceHandle_t& h, size_t at)
    {
        return static_cast<int32_t>((static_cast<uint32_t>(h.value[at]) << 24) |
                       (static_cast<uint32_t>(h.value[at + 1]) << 16) |
                       (static_cast<uint32_t>(h.value[at + 2]) << 8) | h.value[at + 3]);
    }

    static bool zero(const frtps::InstanceHandle_t& h, size_t from)
    {
        for (size_t i = from; i < 16; i++)
        {
            if (h.value[i] != 0)
            {
                return false;
            }
        }
        return true;
    }

    // The id of an instance not seen with data (a dispose or unregister of an
    // instance this reader never saw alive). Two forms reach us:
    //  - the key hash (KeyedType::getKey): the id as 4 big-endian bytes, then
    //    12 zero bytes; what Fast DDS and Courier send;
    //  - the serialized key: Fast DDS 2.9 copies the payload of a key-only
    //    DATA (what Cyclone DDS sends for a dispose) into the instance handle,
    //    over any KEY_HASH in its inline QoS: a 4-byte CDR encapsulation
    //    header (00 00 big-endian or 00 01 little-endian, options 00 00), the
    //    id in that byte order, then 8 zero bytes. Fast DDS then tracks that
    //    dispose as an instance of its own, so a real Fast DDS application
    //    would not see its instance disposed; this peer reports the id on the
    //    wire and says so on stderr.
    int32_t id_of(const frtps::InstanceHandle_t& h)
    {
        auto it = ids.find(h);
        if (it != ids.end())
        {
            return it->second;
        }
        bool hash_form = zero(h, 4);
        bool ser_form = h.value[0] == 0 && h.value[1] <= 1 && h.value[2] == 0 &&
                h.value[3] == 0 && zero(h, 8);
        int32_t hash_id = be32(h, 0);
        int32_t ser_id = be32(h, 4);
        if (ser_form && h.value[1] == 1)
        {
            ser_id = static_cast<int32_t>(__builtin_bswap32(static_cast<uint32_t>(ser_id)));
        }
        // Both forms fit only 00 0x 00 00 00..: then the id seen before wins,
        // and the key hash when neither or both were.
        if (ser_form && (!hash_form || (states.count(ser_id) && !states.count(hash_id))))
        {
            if (!noted_serialized_key)
            {
                noted_serialized_key = true;
                std::fprintf(stderr, "%s: note: instance handle of a key-only DATA holds the "
                        "serialized key (Fast DDS 2.9 ignores its KEY_HASH); decoded id %d\n",
                        PROG, ser_id);
            }
            return ser_id;
        }
        if (!hash_form)
        {
            std::fprintf(stderr, "%s: note: instance handle %s is neither a key hash nor a "
                    "serialized key\n", PROG, hex(h).c_str());
        }
        return hash_id;
    }

    static std::string hex(const frtps::InstanceHandle_t& h)
    {
        std::string out;
        char b[3];
        for (size_t i = 0; i < 16; i++)
        {
            std::snprintf(b, sizeof b, "%02x", h.value[i]);
            out += b;
        }
        return out;
    }

    // Returns true when it reported a disposal.
    bool update(int32_t id, fdds::InstanceStateKind st)
    {
        auto it = states.find(id);
        fdds::InstanceStateKind prev = it == states.end() ? fdds::ALIVE_INSTANCE_STATE : it->second;
        states[id] = st;
        if (st == prev)
        {
            return false;
        }
        if (st == fdds::NOT_ALIVE_DISPOSED_INSTANCE_STATE)
        {
            emit("disposed %d", id);
            return true;
        }
        if (st == fdds::NOT_ALIVE_NO_WRITERS_INSTANCE_STATE)
        {
            emit("unregistered %d", id);
        }
        return false;
    }

};

// A dispose or unregister of an instance never seen alive, under
// --strict-instances (and always for strkeyed): it did not land on the
// instance the writer meant.
void report_unknown(const fdds::SampleInfo& info)
{
    const char* word = info.instance_state == fdds::NOT_ALIVE_DISPOSED_INSTANCE_STATE ?
            "disposed-unknown" : "unregistered-unknown";
    emit("%s %s", word, InstanceTracker::hex(info.instance_handle).c_str());
}

void run_sub(const Options& o, fdds::DataReader* r)
{
    long received = 0;
    long disposed = 0;
    InstanceTracker tracker;
    Msg m;
    Keyed k;
    StrKeyed sk;
    std::map<frtps::InstanceHandle_t, std::string> names;
    std::map<std::string, fdds::InstanceStateKind> name_states;
    auto finished = [&]()
            {
                if (!o.count_set && !o.disposed_set)
                {
                    return o.run_s > 0 && elapsed_ms() >= o.run_s * 1000;
                }
                return (!o.count_set || received >= o.count) &&
                       (!o.disposed_set || disposed >= o.disposed);
            };
    while (!finished())
    {
        (void)remaining_ms();
        check_matched(r);
        bool any = false;
        while (!finished())
        {
            fdds::SampleInfo info;
            void* data = o.type == Kind::Msg ? static_cast<void*>(&m) :
                    o.type == Kind::Keyed ? static_cast<void*>(&k) : static_cast<void*>(&sk);
            ReturnCode_t rc = r->take_next_sample(data, &info);
            if (rc == ReturnCode_t::RETCODE_NO_DATA)
            {
                break;
            }
            if (rc != ReturnCode_t::RETCODE_OK)
            {
                fail("take_next_sample: " + rc_name(rc));
            }
            any = true;
            if (o.type == Kind::Msg)
            {
                if (info.valid_data)
                {
                    emit("sample %u %s %zu %08x", m.seq, escape_text(m.text).c_str(),
                            m.payload.size(), fnv1a32(m.payload));
                    received++;
                }
            }
            else if (o.type == Kind::StrKeyed)
            {
                // tracked by instance handle: a dispose must land on the
                // instance seen alive (Fast DDS 2.9 finds it by key hash)
                std::string name;
                if (info.valid_data)
                {
                    emit("sample %s %u %s", escape_text(sk.name).c_str(), sk.seq,
                            escape_text(sk.text).c_str());
                    received++;
                    names[info.instance_handle] = sk.name;
                    name = sk.name;
                }
                else
                {
                    auto it = names.find(info.instance_handle);
                    if (it == names.end())
                    {
                        report_unknown(info);
                        continue;
                    }
                    name = it->second;
                }
                auto st = name_states.find(name);
                auto prev = st == name_states.end() ? fdds::ALIVE_INSTANCE_STATE : st->second;
                name_states[name] = info.instance_state;
                if (info.instance_state != prev)
                {
                    if (info.instance_state == fdds::NOT_ALIVE_DISPOSED_INSTANCE_STATE)
                    {
                        emit("disposed %s", escape_text(name).c_str());
                        disposed++;
                    }
                    else if (info.instance_state == fdds::NOT_ALIVE_NO_WRITERS_INSTANCE_STATE)
                    {
                        emit("unregistered %s", escape_text(name).c_str());
                    }
                }
            }
            else
            {
                int32_t id;
                if (info.valid_data)
                {
                    emit("sample %d %u %s", k.id, k.seq, escape_text(k.text).c_str());
                    received++;
                    tracker.learn(info.instance_handle, k.id);
                    id = k.id;
                }
                else if (o.strict_instances && !tracker.ids.count(info.instance_handle))
                {
                    report_unknown(info);
                    continue;
                }
                else
                {
                    id = tracker.id_of(info.instance_handle);
                }
                if (tracker.update(id, info.instance_state))
                {
                    disposed++;
                }
            }
        }
        if (!any && !finished())
        {
            wakeup.wait(50);
        }
    }
    // Stay a while so that the writer sees this reader's acknowledgements.
    if (o.linger_ms)
    {
        int64_t until = elapsed_ms() + o.linger_ms;
        while (elapsed_ms() < until)
        {
            sleep_ms(std::min<int64_t>(until - elapsed_ms(), 50));
            check_matched(r);
        }
    }
    emit("done");
}

/* ROS 2-style service over rq/<topic>Request and rr/<topic>Reply, the way
 * rmw_fastrtps does it: a reply names its request with WriteParams'
 * related_sample_identity (PID 0x800f on the wire). */
void run_serve(const Options& o, fdds::DataReader* r, fdds::DataWriter* w)
{
    long served = 0;
    Msg m;
    while (served < o.count)
    {
        (void)remaining_ms();
        fdds::SampleInfo info;
        ReturnCode_t rc = r->take_next_sample(&m, &info);
        if (rc == ReturnCode_t::RETCODE_NO_DATA)
        {
            wakeup.wait(20);
            continue;
        }
        if (rc != ReturnCode_t::RETCODE_OK)
        {
            fail("take_next_sample: " + rc_name(rc));
        }
        if (!info.valid_data)
        {
            continue;
        }
        emit("request %u %s", m.seq, escape_text(m.text).c_str());
        Msg reply = m;
        reply.text = "re:" + m.text;
        eprosima::fastrtps::rtps::WriteParams wp;
        wp.related_sample_identity(info.sample_identity);
        if (!w->write(&reply, wp))
        {
            fail("write reply");
        }
        served++;
    }
    for (;;)
    {
        int64_t left = remaining_ms();
        ReturnCode_t rc = w->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(
                    0, static_cast<uint32_t>(std::min<int64_t>(left, 100) * 1000000)));
        if (rc == ReturnCode_t::RETCODE_OK)
        {
            break;
        }
    }
    emit("done");
}

void run_request(const Options& o, fdds::DataWriter* w, fdds::DataReader* r)
{
    for (;;)
    {
        (void)remaining_ms();
        fdds::PublicationMatchedStatus ps;
        fdds::SubscriptionMatchedStatus ss;
        w->get_publication_matched_status(ps);
        r->get_subscription_matched_status(ss);
        if (ps.current_count > 0 && ss.current_count > 0)
        {
            break;
        }
        wakeup.wait(20);
    }
    emit("matched 1");
    sleep_ms(o.settle_ms);
    Msg m;
    for (long n = 1; n <= o.count; n++)
    {
        Msg req;
        req.seq = static_cast<uint32_t>(n);
        req.text = (o.text_set ? o.text : std::string("fastdds")) + "-" + std::to_string(n);
        eprosima::fastrtps::rtps::WriteParams wp;
        if (!w->write(&req, wp))
        {
            fail("write request");
        }
        const eprosima::fastrtps::rtps::SampleIdentity id = wp.sample_identity();
        for (;;)
        {
            (void)remaining_ms();
            fdds::SampleInfo info;
            ReturnCode_t rc = r->take_next_sample(&m, &info);
            if (rc == ReturnCode_t::RETCODE_NO_DATA)
            {
                wakeup.wait(20);
                continue;
            }
            if (rc != ReturnCode_t::RETCODE_OK)
            {
                fail("take_next_sample: " + rc_name(rc));
            }
            if (!info.valid_data)
            {
                continue;
            }
            bool ours = info.related_sample_identity == id;
            emit("reply %u %s %s", m.seq, escape_text(m.text).c_str(), ours ? "related" : "unrelated");
            if (ours)
            {
                break;
            }
        }
    }
    emit("done");
}

} // namespace

int main(int argc, char** argv)
{
    initial_ppid = getppid();
    Options o = parse_args(argc, argv);
    timeout_ms_total = o.timeout_s * 1000;
    quiet_environment();

    // Fast DDS logs to stdout by default: keep stdout for our lines only.
    fdds::Log::ClearConsumers();
    fdds::Log::RegisterConsumer(std::unique_ptr<fdds::LogConsumer>(new StderrLog()));
    fdds::Log::SetVerbosity(o.trace.empty() ? fdds::Log::Kind::Warning : fdds::Log::Kind::Info);
    if (!o.trace.empty())
    {
        std::fprintf(stderr, "%s: --trace: Fast DDS log goes to stderr (file %s unused)\n", PROG,
                o.trace.c_str());
    }

    auto factory = fdds::DomainParticipantFactory::get_instance();
    fdds::DomainParticipant* participant = factory->create_participant(
        static_cast<fdds::DomainId_t>(o.domain), loopback_participant_qos());
    if (participant == nullptr)
    {
        fail("create_participant failed");
    }

    fdds::TypeSupport type(o.type == Kind::Msg ? static_cast<fdds::TopicDataType*>(new MsgType()) :
            o.type == Kind::Keyed ? static_cast<fdds::TopicDataType*>(new KeyedType()) :
            static_cast<fdds::TopicDataType*>(new StrKeyedType()));
    if (type.register_type(participant) != ReturnCode_t::RETCODE_OK)
    {
        fail("register_type failed");
    }
    if (o.role >= 3)
    {
        fdds::Topic* rq = participant->create_topic("rq/" + o.topic + "Request",
                        type.get_type_name(), fdds::TopicQos());
        fdds::Topic* rr = participant->create_topic("rr/" + o.topic + "Reply",
                        type.get_type_name(), fdds::TopicQos());
        fdds::Publisher* pub = participant->create_publisher(fdds::PublisherQos());
        fdds::Subscriber* sub = participant->create_subscriber(fdds::SubscriberQos());
        if (rq == nullptr || rr == nullptr || pub == nullptr || sub == nullptr)
        {
            fail("service entities");
        }
        fdds::DataWriterQos wq;
        apply_writer_qos(wq, o);
        fdds::DataReaderQos rdq;
        apply_endpoint_qos(rdq, o);
        fdds::DataWriter* w = pub->create_datawriter(o.role == 3 ? rr : rq, wq);
        fdds::DataReader* r = sub->create_datareader(o.role == 3 ? rq : rr, rdq);
        if (w == nullptr || r == nullptr)
        {
            fail("service reader/writer");
        }
        emit("ready");
        if (o.role == 3)
        {
            run_serve(o, r, w);
        }
        else
        {
            run_request(o, w, r);
        }
        participant->delete_contained_entities();
        factory->delete_participant(participant);
        return 0;
    }
    fdds::Topic* topic = participant->create_topic(o.topic, type.get_type_name(), fdds::TopicQos());
    if (topic == nullptr)
    {
        fail("create_topic failed");
    }

    WriterListener wlistener;
    ReaderListener rlistener;
    fdds::Publisher* publisher = nullptr;
    fdds::Subscriber* subscriber = nullptr;
    fdds::DataWriter* writer = nullptr;
    fdds::DataReader* reader = nullptr;
    if (o.role == 1)
    {
        publisher = participant->create_publisher(fdds::PublisherQos());
        if (publisher == nullptr)
        {
            fail("create_publisher failed");
        }
        fdds::DataWriterQos wq;
        apply_writer_qos(wq, o);
        if (o.transient_local)
        {
            wq.durability_service().history_kind = wq.history().kind;
            wq.durability_service().history_depth = wq.history().depth;
        }
        wq.writer_data_lifecycle().autodispose_unregistered_instances = o.autodispose;
        fdds::StatusMask wmask = fdds::StatusMask::publication_matched();
        if (o.liveliness)
        {
            wmask << fdds::StatusMask::liveliness_lost();
        }
        writer = publisher->create_datawriter(topic, wq, &wlistener, wmask);
        if (writer == nullptr)
        {
            fail("create_datawriter failed");
        }
    }
    else
    {
        subscriber = participant->create_subscriber(fdds::SubscriberQos());
        if (subscriber == nullptr)
        {
            fail("create_subscriber failed");
        }
        fdds::DataReaderQos rq;
        apply_endpoint_qos(rq, o);
        fdds::StatusMask rmask =
                fdds::StatusMask::data_available() << fdds::StatusMask::subscription_matched();
        if (o.liveliness)
        {
            rmask << fdds::StatusMask::liveliness_changed();
        }
        reader = subscriber->create_datareader(topic, rq, &rlistener, rmask);
        if (reader == nullptr)
        {
            fail("create_datareader failed");
        }
    }

    emit("ready");
    if (writer != nullptr)
    {
        check_matched(writer);
        run_pub(o, writer);
    }
    else
    {
        check_matched(reader);
        run_sub(o, reader);
    }

    if (participant->delete_contained_entities() != ReturnCode_t::RETCODE_OK ||
            factory->delete_participant(participant) != ReturnCode_t::RETCODE_OK)
    {
        fail("delete participant failed");
    }
    return 0;
}
