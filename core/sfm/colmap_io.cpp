#include "core/sfm/colmap_io.h"

#include <Eigen/Geometry>
#include <fstream>
#include <iomanip>
#include <map>
#include <sstream>

namespace uavm::sfm {

namespace {
constexpr double kColmapShift = 0.5;

bool NextDataLine(std::istream& in, std::string* line) {
  while (std::getline(in, *line)) {
    if (!line->empty() && line->back() == '\r') line->pop_back();
    if (line->empty() || (*line)[0] == '#') continue;
    return true;
  }
  return false;
}
}  // namespace

bool WriteColmapText(const Reconstruction& rec, const std::string& dir, std::string* error) {
  std::ofstream cams(dir + "/cameras.txt"), ims(dir + "/images.txt"), pts(dir + "/points3D.txt");
  if (!cams || !ims || !pts) {
    *error = "cannot write the COLMAP model into " + dir;
    return false;
  }
  cams << std::setprecision(17);
  cams << "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
       << "# Number of cameras: " << rec.cameras.size() << '\n';
  for (size_t id = 0; id < rec.cameras.size(); ++id) {  // CAMERA_ID = index + 1
    const Camera& c = rec.cameras[id];
    cams << id + 1 << (c.k3 == 0.0 ? " OPENCV " : " FULL_OPENCV ") << c.width << ' ' << c.height << ' ' << c.fx << ' '
         << c.fy << ' ' << c.cx + kColmapShift << ' ' << c.cy + kColmapShift << ' ' << c.k1 << ' ' << c.k2 << ' '
         << c.p1 << ' ' << c.p2;
    if (c.k3 != 0.0) cams << ' ' << c.k3 << " 0 0 0";
    cams << '\n';
  }
  // POINT3D_ID per (image, feature).
  std::vector<std::vector<long>> point_of(rec.images.size());
  for (size_t i = 0; i < rec.images.size(); ++i) point_of[i].assign(rec.images[i].keypoints.size(), -1);
  for (size_t p = 0; p < rec.points.size(); ++p) {
    for (const auto& o : rec.points[p].track) {
      point_of[static_cast<size_t>(o.image)][static_cast<size_t>(o.feature)] = static_cast<long>(p + 1);
    }
  }
  ims << std::setprecision(17);
  ims << "# Image list with two lines of data per image:\n"
      << "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
      << "# Number of images: " << rec.images.size() << '\n';
  for (size_t i = 0; i < rec.images.size(); ++i) {
    const auto& im = rec.images[i];
    const Eigen::Quaterniond q(im.pose.R);
    const Eigen::Vector3d t = im.pose.t();
    ims << i + 1 << ' ' << q.w() << ' ' << q.x() << ' ' << q.y() << ' ' << q.z() << ' ' << t.x() << ' ' << t.y() << ' '
        << t.z() << ' ' << im.camera + 1 << ' ' << im.name << '\n';
    for (size_t k = 0; k < im.keypoints.size(); ++k) {
      if (k) ims << ' ';
      ims << im.keypoints[k].x() + kColmapShift << ' ' << im.keypoints[k].y() + kColmapShift << ' ' << point_of[i][k];
    }
    ims << '\n';
  }
  pts << std::setprecision(17);
  pts << "# 3D point list with one line of data per point:\n"
      << "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
      << "# Number of points: " << rec.points.size() << '\n';
  for (size_t p = 0; p < rec.points.size(); ++p) {
    const auto& pt = rec.points[p];
    pts << p + 1 << ' ' << pt.X.x() << ' ' << pt.X.y() << ' ' << pt.X.z() << ' ' << int(pt.bgr[2]) << ' '
        << int(pt.bgr[1]) << ' ' << int(pt.bgr[0]) << ' ' << pt.error_px;
    for (const auto& o : pt.track) pts << ' ' << o.image + 1 << ' ' << o.feature;
    pts << '\n';
  }
  cams.close();
  ims.close();
  pts.close();
  if (!cams || !ims || !pts) {
    *error = "write error in the COLMAP model in " + dir;
    return false;
  }
  return true;
}

bool ReadColmapText(const std::string& dir, Reconstruction* rec, std::string* error) {
  std::ifstream cams(dir + "/cameras.txt"), ims(dir + "/images.txt"), pts(dir + "/points3D.txt");
  if (!cams || !ims) {
    *error = "no cameras.txt/images.txt in " + dir;
    return false;
  }
  *rec = Reconstruction{};
  std::string line;
  std::map<int, int> camera_of_id;
  while (NextDataLine(cams, &line)) {
    std::istringstream s(line);
    int id = 0;
    std::string model;
    Camera c;
    s >> id >> model >> c.width >> c.height;
    if (model == "OPENCV" || model == "FULL_OPENCV") {
      s >> c.fx >> c.fy >> c.cx >> c.cy >> c.k1 >> c.k2 >> c.p1 >> c.p2;
      if (model == "FULL_OPENCV") s >> c.k3;
    } else if (model == "PINHOLE") {
      s >> c.fx >> c.fy >> c.cx >> c.cy;
    } else if (model == "SIMPLE_RADIAL" || model == "RADIAL") {
      s >> c.fx >> c.cx >> c.cy >> c.k1;
      c.fy = c.fx;
      if (model == "RADIAL") s >> c.k2;
    } else {
      *error = "cameras.txt: unsupported model " + model;
      return false;
    }
    if (!s) {
      *error = "cameras.txt: malformed camera line";
      return false;
    }
    c.cx -= kColmapShift;
    c.cy -= kColmapShift;
    camera_of_id[id] = static_cast<int>(rec->cameras.size());
    rec->cameras.push_back(c);
  }
  if (rec->cameras.empty()) {
    *error = "cameras.txt: no camera";
    return false;
  }
  std::map<long, size_t> image_of_id;
  while (NextDataLine(ims, &line)) {
    std::istringstream s(line);
    long id = 0;
    int cam_id = 0;
    double qw, qx, qy, qz, tx, ty, tz;
    Image im;
    s >> id >> qw >> qx >> qy >> qz >> tx >> ty >> tz >> cam_id >> im.name;
    if (!s) {
      *error = "images.txt: malformed image line";
      return false;
    }
    const auto camera = camera_of_id.find(cam_id);
    if (camera == camera_of_id.end()) {
      *error = "images.txt: image " + im.name + " has an unknown camera id";
      return false;
    }
    im.camera = camera->second;
    im.pose.R = Eigen::Quaterniond(qw, qx, qy, qz).normalized().toRotationMatrix();
    im.pose.c = -im.pose.R.transpose() * Eigen::Vector3d(tx, ty, tz);
    std::string pts_line;
    std::getline(ims, pts_line);
    std::istringstream ps(pts_line);
    double x, y;
    long pid;
    while (ps >> x >> y >> pid) im.keypoints.emplace_back(x - kColmapShift, y - kColmapShift);
    image_of_id[id] = rec->images.size();
    rec->images.push_back(std::move(im));
  }
  if (pts) {
    while (NextDataLine(pts, &line)) {
      std::istringstream s(line);
      long id;
      int r, g, b;
      Point3D p;
      s >> id >> p.X.x() >> p.X.y() >> p.X.z() >> r >> g >> b >> p.error_px;
      if (!s) {
        *error = "points3D.txt: malformed point line";
        return false;
      }
      p.bgr = cv::Vec3b(static_cast<uchar>(b), static_cast<uchar>(g), static_cast<uchar>(r));
      long img;
      int feat;
      while (s >> img >> feat) {
        const auto it = image_of_id.find(img);
        if (it == image_of_id.end()) {
          *error = "points3D.txt: unknown image id";
          return false;
        }
        p.track.push_back({static_cast<int>(it->second), feat});
      }
      rec->points.push_back(std::move(p));
    }
  }
  return true;
}

}  // namespace uavm::sfm
