#include "src/core/pose2.h"

namespace stereoloc {

Matrix2d Pose2::rotation() const {
  const double c = std::cos(theta), s = std::sin(theta);
  Matrix2d R;
  R << c, -s, s, c;
  return R;
}

Pose2 compose(const Pose2& a, const Pose2& b, Matrix3d* J_out_a, Matrix3d* J_out_b) {
  const double c = std::cos(a.theta), s = std::sin(a.theta);
  const double dx = c * b.x - s * b.y;  // (B.14)
  const double dy = s * b.x + c * b.y;  // (B.15)
  if (J_out_a) {  // (B.18)
    *J_out_a << 1, 0, -dy,  //
        0, 1, dx,           //
        0, 0, 1;
  }
  if (J_out_b) {  // (B.19)
    *J_out_b << c, -s, 0,  //
        s, c, 0,           //
        0, 0, 1;
  }
  return Pose2(a.x + dx, a.y + dy, a.theta + b.theta);
}

Pose2 inverse(const Pose2& p, Matrix3d* J_out_p) {
  const double c = std::cos(p.theta), s = std::sin(p.theta);
  const Pose2 out(-c * p.x - s * p.y, s * p.x - c * p.y, -p.theta);
  if (J_out_p) {
    *J_out_p << -c, -s, out.y,  //
        s, -c, -out.x,          //
        0, 0, -1;
  }
  return out;
}

Pose2 between(const Pose2& a, const Pose2& b, Matrix3d* J_out_a, Matrix3d* J_out_b) {
  const double c = std::cos(a.theta), s = std::sin(a.theta);
  const double dx = b.x - a.x, dy = b.y - a.y;
  const Pose2 out(c * dx + s * dy, -s * dx + c * dy, b.theta - a.theta);
  if (J_out_a) {
    *J_out_a << -c, -s, out.y,  //
        s, -c, -out.x,          //
        0, 0, -1;
  }
  if (J_out_b) {
    *J_out_b << c, s, 0,  //
        -s, c, 0,         //
        0, 0, 1;
  }
  return out;
}

Pose2 plus(const Pose2& p, const Vector3d& delta) {
  return Pose2(p.x + delta.x(), p.y + delta.y(), p.theta + delta.z());
}

Vector3d minus(const Pose2& a, const Pose2& b) {
  return Vector3d(a.x - b.x, a.y - b.y, angleDiff(a.theta, b.theta));
}

Vector2d transformToLocal(const Pose2& p, const Vector2d& world, Matrix23d* J_out_p, Matrix2d* J_out_world) {
  const double c = std::cos(p.theta), s = std::sin(p.theta);
  const double dx = world.x() - p.x, dy = world.y() - p.y;
  const Vector2d local(c * dx + s * dy, -s * dx + c * dy);
  if (J_out_p) {
    *J_out_p << -c, -s, local.y(),  //
        s, -c, -local.x();
  }
  if (J_out_world) {
    *J_out_world << c, s, -s, c;
  }
  return local;
}

Vector2d transformToWorld(const Pose2& p, const Vector2d& local) {
  return p.rotation() * local + p.translation();
}

}  // namespace stereoloc
