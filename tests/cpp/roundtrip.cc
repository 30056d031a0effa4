// A C++ client's side of the wire, built only from the code protoc generates from schemas/afford/v1
// (tests/test_cpp_client.py compiles it with g++ -Wall -Wextra -Werror and runs it):
//
//   roundtrip write-scan OUT.bin < points.txt   reads "x y z" lines, writes an afford.v1.Scan of packed
//                                               little-endian float32 x, y, z (stride 12) to OUT.bin
//   roundtrip read-map IN.bin                   reads an afford.v1.AffordanceMap and prints its contents,
//                                               one "name value..." line per item
//
// Packed arrays are little-endian whatever the host: floats are moved through their IEEE-754 bits.
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iostream>
#include <iterator>
#include <limits>
#include <string>
#include <vector>

#include "afford/v1/maps.pb.h"
#include "afford/v1/sensing.pb.h"

namespace {

const char* const kJoints[15] = {"HEAD",  "NECK",   "TORSO", "L_SHOULDER", "L_ELBOW",
                                 "R_SHOULDER", "R_ELBOW", "L_HIP", "L_KNEE", "R_HIP",
                                 "R_KNEE", "L_HAND", "R_HAND", "L_FOOT", "R_FOOT"};

void AppendFloat32LE(std::string* out, float value) {
  std::uint32_t bits = 0;
  std::memcpy(&bits, &value, sizeof bits);
  for (int byte = 0; byte < 4; ++byte) out->push_back(static_cast<char>((bits >> (8 * byte)) & 0xFFu));
}

float Float32LE(const std::string& data, std::size_t index) {
  std::uint32_t bits = 0;
  for (int byte = 0; byte < 4; ++byte) {
    bits |= static_cast<std::uint32_t>(static_cast<unsigned char>(data[4 * index + byte])) << (8 * byte);
  }
  float value = 0.0f;
  std::memcpy(&value, &bits, sizeof value);
  return value;
}

int WriteScan(const char* path) {
  afford::v1::Scan scan;
  scan.set_frame_id("lidar");
  scan.mutable_timestamp()->set_seconds(1767225600);  // 2026-01-01T00:00:00Z
  scan.mutable_timestamp()->set_nanos(250000000);
  const char* const names[3] = {"x", "y", "z"};
  for (int axis = 0; axis < 3; ++axis) {
    afford::v1::PackedElementField* field = scan.add_fields();
    field->set_name(names[axis]);
    field->set_offset(static_cast<std::uint32_t>(4 * axis));
    field->set_type(afford::v1::PackedElementField::FLOAT32);
  }
  scan.set_point_stride(12);
  std::string data;
  float x = 0.0f, y = 0.0f, z = 0.0f;
  std::size_t points = 0;
  while (std::cin >> x >> y >> z) {
    AppendFloat32LE(&data, x);
    AppendFloat32LE(&data, y);
    AppendFloat32LE(&data, z);
    ++points;
  }
  if (!std::cin.eof()) {
    std::cerr << "points must be lines of three numbers\n";
    return 2;
  }
  scan.set_data(data);
  std::ofstream out(path, std::ios::binary);
  if (!out || !scan.SerializeToOstream(&out)) {
    std::cerr << "cannot write " << path << "\n";
    return 1;
  }
  std::cout << "wrote scan " << points << " points " << scan.ByteSizeLong() << " bytes\n";
  return 0;
}

int ReadMap(const char* path) {
  std::ifstream in(path, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  afford::v1::AffordanceMap map;
  if (!in.good() && !in.eof()) {
    std::cerr << "cannot read " << path << "\n";
    return 1;
  }
  if (!map.ParseFromString(bytes)) {
    std::cerr << path << " is not an afford.v1.AffordanceMap\n";
    return 1;
  }
  std::cout.precision(std::numeric_limits<double>::max_digits10);
  std::cout << "affordance " << map.affordance() << "\n"
            << "model " << map.model() << "\n"
            << "frame_id " << map.frame_id() << "\n"
            << "threshold " << map.threshold() << "\n"
            << "place_threshold " << map.place_threshold() << "\n"
            << "frames " << map.frames() << "\n"
            << "cloud_timestamp " << map.cloud_timestamp().seconds() << " " << map.cloud_timestamp().nanos()
            << "\n";
  const afford::v1::PoseGridSpec& grid = map.grid();
  std::cout << "grid " << grid.x0() << " " << grid.y0() << " " << grid.step() << " " << grid.nx() << " "
            << grid.ny() << " " << grid.theta_step() << " " << grid.n_theta() << "\n";
  std::cout << "grid_z";
  for (double z : grid.z()) std::cout << " " << z;
  std::cout << "\n";
  const afford::v1::Pose& pose = map.world_from_input();
  std::cout << "world_from_input " << pose.position().x() << " " << pose.position().y() << " "
            << pose.position().z() << " " << pose.orientation().x() << " " << pose.orientation().y() << " "
            << pose.orientation().z() << " " << pose.orientation().w() << "\n";

  std::cout << "skeletons " << map.skeletons_size() << "\n";
  for (int s = 0; s < map.skeletons_size(); ++s) {
    const afford::v1::PlacedSkeleton& skeleton = map.skeletons(s);
    std::cout << "skeleton " << s << " " << skeleton.x() << " " << skeleton.y() << " " << skeleton.z() << " "
              << skeleton.theta() << " " << skeleton.score() << "\n";
    if (skeleton.joints_size() != 45) {
      std::cerr << "skeleton " << s << " has " << skeleton.joints_size() << " joint values, not 45\n";
      return 1;
    }
    for (int j = 0; j < 15; ++j) {
      std::cout << "joint " << s << " " << kJoints[j] << " " << skeleton.joints(3 * j) << " "
                << skeleton.joints(3 * j + 1) << " " << skeleton.joints(3 * j + 2) << "\n";
    }
  }

  if (map.positives().size() % 20 != 0) {
    std::cerr << "positives are not rows of five float32\n";
    return 1;
  }
  const std::size_t positives = map.positives().size() / 20;
  std::cout << "positives " << positives << "\n";
  for (std::size_t row = 0; row < positives && row < 3; ++row) {
    std::cout << "positive " << row;
    for (std::size_t column = 0; column < 5; ++column) std::cout << " " << Float32LE(map.positives(), 5 * row + column);
    std::cout << "\n";
  }

  const std::size_t cells = static_cast<std::size_t>(grid.nx()) * grid.ny();
  if (map.confidence().size() != 4 * cells) {
    std::cerr << "confidence holds " << map.confidence().size() << " bytes, not " << 4 * cells << "\n";
    return 1;
  }
  std::size_t best = 0;
  for (std::size_t cell = 1; cell < cells; ++cell) {
    if (Float32LE(map.confidence(), cell) > Float32LE(map.confidence(), best)) best = cell;
  }
  if (cells > 0) {
    // cell (i, j) is element i * ny + j: x = x0 + i * step, y = y0 + j * step
    std::cout << "confidence_best " << best / grid.ny() << " " << best % grid.ny() << " "
              << Float32LE(map.confidence(), best) << "\n";
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  GOOGLE_PROTOBUF_VERIFY_VERSION;
  int status = 2;
  if (argc == 3 && std::string(argv[1]) == "write-scan") {
    status = WriteScan(argv[2]);
  } else if (argc == 3 && std::string(argv[1]) == "read-map") {
    status = ReadMap(argv[2]);
  } else {
    std::cerr << "usage: roundtrip write-scan OUT.bin < points.txt | roundtrip read-map IN.bin\n";
  }
  google::protobuf::ShutdownProtobufLibrary();
  return status;
}
