#include <gtest/gtest.h>

#include "src/core/atomic_file.h"
#include "src/core/error.h"
#include "src/core/field_map.h"
#include "test_util.h"

namespace stereoloc {
namespace {

std::string errorOf(const std::string& path) {
  try {
    FieldMap::load(path);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

const char* kHeader = "%YAML:1.0\n---\nname: test\nbounds: { xmin: 0., ymin: 0., xmax: 100., ymax: 100. }\n";

}  // namespace

TEST(FieldMap, MiroSotGeometryAndLandmarks) {
  const FieldMap m = FieldMap::miroSot();
  ASSERT_TRUE(m.geometry().has_value());
  EXPECT_DOUBLE_EQ(m.geometry()->length, 1500);
  EXPECT_DOUBLE_EQ(m.geometry()->width, 1300);
  const auto goals = m.ofType(LandmarkType::GoalCorner);
  ASSERT_EQ(goals.size(), 4u);
  int blue = 0, yellow = 0;
  for (const Landmark* g : goals) {
    EXPECT_TRUE(g->unique);
    EXPECT_TRUE(g->position.y() == 450 || g->position.y() == 850);
    if (g->color == GoalColor::Blue) {
      ++blue;
      EXPECT_EQ(g->position.x(), 0);
    } else {
      ++yellow;
      EXPECT_EQ(g->position.x(), 1500);
    }
  }
  EXPECT_EQ(blue, 2);
  EXPECT_EQ(yellow, 2);
  for (const Landmark& l : m.landmarks()) {
    if (l.type != LandmarkType::GoalCorner) {
      EXPECT_FALSE(l.unique) << l.name;
    }
  }
  EXPECT_EQ(m.ofType(LandmarkType::MarkingCorner).size(), 8u);
  EXPECT_EQ(m.ofType(LandmarkType::Junction).size(), 10u);
  EXPECT_EQ(m.ofType(LandmarkType::Intersection).size(), 2u);
  // Goal-area corner of the blue goal at (150, 400); halfway line crosses the circle at y = 400.
  bool found = false;
  for (const Landmark* l : m.ofType(LandmarkType::MarkingCorner)) found |= l->xy().isApprox(Eigen::Vector2d(150, 400));
  EXPECT_TRUE(found);
  EXPECT_THROW(m.at(999), Error);
  EXPECT_EQ(m.find(0)->id, 0);
}

TEST(FieldMap, YamlRoundTripAndShippedFile) {
  test::TempDir dir;
  const FieldMap m = FieldMap::miroSot();
  m.save(dir.file("map.yaml"));
  const FieldMap back = FieldMap::load(dir.file("map.yaml"));
  ASSERT_EQ(back.landmarks().size(), m.landmarks().size());
  for (size_t i = 0; i < m.landmarks().size(); ++i) {
    const Landmark &a = m.landmarks()[i], &b = back.landmarks()[i];
    EXPECT_EQ(a.id, b.id);
    EXPECT_EQ(a.type, b.type);
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.unique, b.unique);
    EXPECT_EQ(a.color, b.color);
    EXPECT_EQ(a.position, b.position);
  }
  ASSERT_TRUE(back.geometry().has_value());
  EXPECT_DOUBLE_EQ(back.geometry()->penalty_area_width, 800);
  const FieldMap shipped = FieldMap::load(std::string(STEREOLOC_DATA_DIR) + "/field_mirosot.yaml");
  EXPECT_EQ(shipped.landmarks().size(), m.landmarks().size());
  for (size_t i = 0; i < m.landmarks().size(); ++i)
    EXPECT_EQ(shipped.landmarks()[i].position, m.landmarks()[i].position);
}

// A measured field states how well it knows its dimensions (their covariance); the file carries
// it, a changed field no longer does, and one that is not a covariance is an error naming the
// file and the key.
TEST(FieldMap, StatesHowWellItKnowsItsDimensions) {
  test::TempDir dir;
  FieldDimensionMatrix a = FieldDimensionMatrix::Zero();
  for (int i = 0; i < kFieldDimensionCount; ++i)
    for (int j = 0; j <= i; ++j) a(i, j) = 0.3 * (i + 1) - 0.1 * j;
  const FieldDimensionMatrix covariance = a * a.transpose() + FieldDimensionMatrix::Identity();  // correlated
  const FieldMap m = FieldMap::miroSot().withDimensionCovariance(covariance);
  ASSERT_TRUE(m.dimensionCovariance().has_value());
  EXPECT_EQ(*m.dimensionCovariance(), covariance);
  EXPECT_FALSE(FieldMap::miroSot().dimensionCovariance().has_value());
  m.save(dir.file("measured.yaml"));
  const FieldMap back = FieldMap::load(dir.file("measured.yaml"));
  ASSERT_TRUE(back.dimensionCovariance().has_value());
  EXPECT_LT((*back.dimensionCovariance() - covariance).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_FALSE(m.withDimensionChange(FieldDimensionVector::Ones()).dimensionCovariance().has_value());

  FieldDimensionMatrix singular = covariance;
  singular.row(2).setZero();
  singular.col(2).setZero();
  EXPECT_THROW(FieldMap::miroSot().withDimensionCovariance(singular), Error);
  const FieldMap own("own", FieldMap::miroSot().bounds(), {});
  EXPECT_THROW(own.withDimensionCovariance(covariance), Error);  // no geometry: no dimensions to know

  FieldMap::miroSot().withDimensionCovariance(FieldDimensionMatrix::Identity()).save(dir.file("unit.yaml"));
  std::string text = test::readFile(dir.file("unit.yaml"));
  const size_t at = text.find("data: [ 1.", text.find("dimension_covariance_mm2"));
  ASSERT_NE(at, std::string::npos) << text;
  text.replace(at, 10, "data: [ -1.");
  writeFileAtomically(dir.file("negative.yaml"), text);
  std::string e = errorOf(dir.file("negative.yaml"));
  EXPECT_NE(e.find("negative.yaml: "), std::string::npos) << e;
  EXPECT_NE(e.find("dimension_covariance_mm2: not positive definite"), std::string::npos) << e;
  text = test::readFile(dir.file("unit.yaml"));
  text.replace(text.find("rows: 9", text.find("dimension_covariance_mm2")), 7, "rows: 3");
  text.replace(text.find("cols: 9", text.find("dimension_covariance_mm2")), 7, "cols: 27");
  writeFileAtomically(dir.file("shape.yaml"), text);
  e = errorOf(dir.file("shape.yaml"));
  EXPECT_NE(e.find("shape.yaml: dimension_covariance_mm2"), std::string::npos) << e;
  EXPECT_NE(e.find("9 x 9"), std::string::npos) << e;
}

TEST(FieldMap, BadMapsGiveErrorsNamingFileAndKey) {
  test::TempDir dir;
  auto write = [&](const std::string& name, const std::string& body) {
    writeFileAtomically(dir.file(name), body);
    return dir.file(name);
  };
  std::string e = errorOf(write("missing.yaml", std::string(kHeader) + "landmarks:\n   - { id: 1, type: point, y: 5. }\n"));
  EXPECT_NE(e.find("missing.yaml"), std::string::npos) << e;
  EXPECT_NE(e.find("landmarks[0].x"), std::string::npos) << e;
  EXPECT_NE(e.find("missing"), std::string::npos) << e;

  e = errorOf(write("nan.yaml", std::string(kHeader) + "landmarks:\n   - { id: 1, type: point, x: .nan, y: 5. }\n"));
  EXPECT_NE(e.find("nan.yaml"), std::string::npos) << e;
  EXPECT_NE(e.find("landmarks[0].x"), std::string::npos) << e;

  e = errorOf(write("dup.yaml", std::string(kHeader) +
                                    "landmarks:\n   - { id: 4, type: point, x: 1., y: 5. }\n   - { id: 4, type: point, x: 2., y: 5. }\n"));
  EXPECT_NE(e.find("dup.yaml"), std::string::npos) << e;
  EXPECT_NE(e.find("duplicate id 4"), std::string::npos) << e;

  e = errorOf(write("outside.yaml", std::string(kHeader) + "landmarks:\n   - { id: 1, type: point, x: 500., y: 5. }\n"));
  EXPECT_NE(e.find("outside.yaml"), std::string::npos) << e;
  EXPECT_NE(e.find("outside"), std::string::npos) << e;

  // A field ten kilometres long is no MiroSot field, and no grid a renderer can hold.
  std::string field = test::readFile(std::string(STEREOLOC_DATA_DIR) + "/field_mirosot.yaml");
  field.replace(field.find("length: 1500."), 13, "length: 1e9");
  e = errorOf(write("long.yaml", field));
  EXPECT_NE(e.find("long.yaml: geometry.length: must be within (0, 10000] mm"), std::string::npos) << e;

  e = errorOf(write("type.yaml", std::string(kHeader) + "landmarks:\n   - { id: 1, type: tower, x: 5., y: 5. }\n"));
  EXPECT_NE(e.find("landmarks[0].type"), std::string::npos) << e;

  e = errorOf(write("nobounds.yaml", "%YAML:1.0\n---\nname: x\nlandmarks: []\n"));
  EXPECT_NE(e.find("nobounds.yaml: bounds: missing"), std::string::npos) << e;

  e = errorOf(write("garbage.yaml", "%YAML:1.0\n---\nname: [unclosed\n"));
  EXPECT_NE(e.find("garbage.yaml"), std::string::npos) << e;

  e = errorOf(dir.file("nonexistent.yaml"));
  EXPECT_NE(e.find("nonexistent.yaml"), std::string::npos) << e;
}

TEST(FieldMap, EnumNamesRoundTrip) {
  for (LandmarkType t : {LandmarkType::GoalCorner, LandmarkType::MarkingCorner, LandmarkType::Junction,
                         LandmarkType::Intersection, LandmarkType::WallCorner, LandmarkType::Point})
    EXPECT_EQ(landmarkTypeFromString(toString(t)), t);
  EXPECT_THROW(landmarkTypeFromString("tower"), Error);
  EXPECT_EQ(goalColorFromString(toString(GoalColor::Yellow)), GoalColor::Yellow);
}

}  // namespace stereoloc
