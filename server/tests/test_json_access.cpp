// Typed JSON access (io/json_access.h): every error names the key path, what
// was expected, and for a number out of bounds the range, unit and reason.
#include "io/json_access.h"

#include <gtest/gtest.h>

#include <string>

namespace fc {
namespace {

using nlohmann::json;
using namespace json_access;

// The error `read` throws: its path, and its what() checked to be "<path>: <message>".
template <class Read>
JsonValueError errorOf(Read&& read) {
  try {
    read();
  } catch (const JsonValueError& e) {
    EXPECT_EQ(std::string(e.what()), e.path.empty() ? e.message : e.path + ": " + e.message);
    return e;
  }
  ADD_FAILURE() << "no error";
  return JsonValueError("", "");
}

TEST(JsonAccess, KeyPathsReadAsTheUserWritesThem) {
  EXPECT_EQ(keyPath("", "solver"), "solver");
  EXPECT_EQ(keyPath("solver", "method"), "solver.method");
  EXPECT_EQ(indexPath(keyPath("fluid_blocks", "min"), 2), "fluid_blocks.min[2]");
}

TEST(JsonAccess, WrongTypesNameWhatWasExpectedAndWhatWasGiven) {
  const json j = json::parse(R"({"a": "fast", "b": [1, 2], "c": 1.5, "d": 3.0, "e": 1})");
  JsonValueError e = errorOf([&] { getNumber(j["a"], "a"); });
  EXPECT_EQ(e.path, "a");
  EXPECT_EQ(e.message, "expected a number, got string \"fast\"");
  EXPECT_EQ(errorOf([&] { getInteger(j["c"], "c"); }).message, "expected an integer, got 1.5");
  EXPECT_EQ(getInteger(j["d"], "d"), 3);  // JSON has one number type
  EXPECT_EQ(errorOf([&] { getBool(j["e"], "e"); }).message, "expected true or false, got number 1");
  EXPECT_EQ(errorOf([&] { expectObject(j["b"], "b"); }).message, "expected an object, got array [1,2]");
  const json big = json::array({std::string(100, 'x')});
  EXPECT_LE(errorOf([&] { getString(big, "big"); }).message.size(), 100u);
}

TEST(JsonAccess, UnknownAndMissingKeysAreErrorsAtTheirPath) {
  const json o = {{"name", "a"}, {"colour", 1}};
  JsonValueError e = errorOf([&] { checkKeys(o, "phases[0]", {"name", "color"}); });
  EXPECT_EQ(e.path, "phases[0].colour");
  EXPECT_EQ(e.message, "unknown key; expected one of: name, color");
  EXPECT_EQ(errorOf([&] { checkKeys(o, "", {"name"}, "a settings edit"); }).message,
            "unknown key for a settings edit; expected one of: name");
  e = errorOf([&] { required(o, "phases[0]", "rest_density", "kg/m^3"); });
  EXPECT_EQ(e.path, "phases[0].rest_density");
  EXPECT_EQ(e.message, "missing required key (kg/m^3)");
  EXPECT_EQ(member(o, "name"), &o["name"]);
  EXPECT_EQ(member(o, "nothing"), nullptr);
}

TEST(JsonAccess, BoundsGiveTheRangeTheUnitAndTheReason) {
  const json body = {{"threads", 9}, {"speed", -1}, {"frames", 2.0}};
  JsonValueError e = errorOf([&] { integerField(body, "", "threads", 0, {0, 8, "", "the ceiling"}); });
  EXPECT_EQ(e.path, "threads");
  EXPECT_EQ(e.message, "9 is outside the allowed range [0, 8] (the ceiling)");
  e = errorOf([&] { numberField(body, "opts", "speed", kRequired, {0, 1e6, "frames/s"}); });
  EXPECT_EQ(e.path, "opts.speed");
  EXPECT_EQ(e.message, "-1 is outside the allowed range [0, 1000000] frames/s");
  EXPECT_EQ(errorOf([&] { checkBounds(5000, "x", {-1000, 1000, "m", "a coordinate", "physical"}); }).message,
            "5000 is outside the physical range [-1000, 1000] m (a coordinate)");
  EXPECT_EQ(integerField(body, "", "frames", kRequired, {1, 10}), 2);
  EXPECT_EQ(integerField(body, "", "absent", 7, {1, 10}), 7);  // the fallback is not checked
  EXPECT_EQ(errorOf([&] { integerField(body, "", "absent", kRequired); }).path, "absent");
  EXPECT_EQ(errorOf([&] { integerField(json{{"n", 1e300}}, "", "n", kRequired); }).path, "n");
  EXPECT_EQ(stringField(body, "", "name", "x"), "x");
  EXPECT_TRUE(boolField(body, "", "force", true));
}

}  // namespace
}  // namespace fc
