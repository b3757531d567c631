/* Serializes the gen.py cases with Cyclone DDS's C core (dds_stream_write_with_byte_order),
   printing "<case>_<enc> <hex payload with encapsulation header>" per line. See check.sh. */
#include <stdio.h>
#include <string.h>
#include "dds/dds.h"
#include "dds/ddsi/ddsi_cdrstream.h"
#include "types.h"

#define SEQ(T, arr) { ._maximum = sizeof(arr)/sizeof(arr[0]), ._length = sizeof(arr)/sizeof(arr[0]), ._buffer = arr, ._release = false }
#define EMPTY { 0, 0, NULL, false }

static void dump(const char *name, const void *sample, const dds_topic_descriptor_t *desc, int ext) {
  for (int v = 1; v <= 2; v++)
    for (int be = 0; be <= 1; be++) {
      dds_ostream_t os;
      dds_ostream_init(&os, 0, v == 1 ? CDR_ENC_VERSION_1 : CDR_ENC_VERSION_2);
      dds_stream_write_with_byte_order(&os, sample, desc->m_ops, be ? DDSRT_BOSEL_BE : DDSRT_BOSEL_LE);
      unsigned id = v == 1 ? (ext == 2 ? 2 : 0) : (ext == 0 ? 6 : ext == 1 ? 8 : 10);
      id |= be ? 0 : 1;
      printf("%s_x%d%s 00%02x0000", name, v, be ? "be" : "le", id);
      for (uint32_t i = 0; i < os.m_index; i++) printf("%02x", os.m_buffer[i]);
      printf("\n");
      dds_ostream_fini(&os);
    }
}

int main(void) {
  int32_t si32[] = {1, 2}; int16_t si16[] = {3, 4, 5}; uint8_t su8[] = {6, 7, 8, 9, 10}; double sf64[] = {1.5};
  Point spts[] = {{1, 1.5}}; int32_t opt = 77; Point optp = {8, 8.5};
  Mut m = { -1, 2, 3, 4, "mut", GREEN, true, {9, 9.5}, SEQ(int32, si32), SEQ(int16, si16), SEQ(uint8, su8), SEQ(double, sf64), SEQ(Point, spts), {11, 12}, {"x", "yz"}, &opt, &optp };
  dump("mutable", &m, &Mut_desc, 2);
  Mut ma = { 0, 0, 0, 0, "", RED, false, {0, 0.0}, EMPTY, EMPTY, EMPTY, EMPTY, EMPTY, {0, 0}, {"", ""}, NULL, NULL };
  dump("mutable_absent", &ma, &Mut_desc, 2);
  int32_t x = 5; double d = 2.5; char *s = "opt";
  Opt op = { 1, &x, &d, s, -1 };
  dump("optional_present", &op, &Opt_desc, 0);
  Opt oa = { 1, NULL, NULL, NULL, -1 };
  dump("optional_absent", &oa, &Opt_desc, 0);
  Point pts[] = {{4, 4.5}, {5, 5.5}};
  int32_t s1[] = {1}, s3[] = {2, 3};
  dds_sequence_int32 ss[] = { SEQ(int32, s1), EMPTY, SEQ(int32, s3) };
  Nested n = { 1, {2, 3.5}, SEQ(Point, pts), {{6, 6.5}, {7, 7.5}}, {{1, 2, 3}, {4, 5, 6}}, {"ab", ""}, SEQ(x, ss) };
  dump("nested", &n, &Nested_desc, 0);
  int32_t i32[] = {1, -2, 3}; int16_t i16[] = {4, -5}; uint8_t u8[] = {6, 7, 8}; double f64[] = {0.5, -1.0}; bool fl[] = {true, false, true}; Color col[] = {GREEN, RED};
  Seqs q = { SEQ(int32, i32), SEQ(int16, i16), SEQ(uint8, u8), SEQ(double, f64), SEQ(bool, fl), SEQ(Color, col), EMPTY };
  dump("seqs", &q, &Seqs_desc, 0);
  Prims pr = { -5, 250, -1234, 54321, -123456789, 3000000000u, -1234567890123LL, 18000000000000000000ULL, 1.5f, -2.25, true, 'Z', BLUE };
  dump("prims", &pr, &Prims_desc, 0);
  Point pt = {7, 0.5};
  dump("point", &pt, &Point_desc, 0);
  char *lst[] = {"a", "", "xyz"};
  Strings st = { "", "hello", 9, SEQ(string, lst) };
  dump("strings", &st, &Strings_desc, 0);
  AppInner items[] = {{1, "a"}, {2, "bc"}};
  App ap = { 42, {3, "in"}, 1.25, SEQ(AppInner, items) };
  dump("appendable", &ap, &App_desc, 1);
  Keyed k = { 17, "key", 3.5 };
  dump("keyed", &k, &Keyed_desc, 0);
  MutKeyed mk = { 17, "val" };
  dump("mutkeyed", &mk, &MutKeyed_desc, 2);
  HelloWorld h = { 0, "final #0" };
  dump("hello", &h, &HelloWorld_desc, 0);
  return 0;
}
