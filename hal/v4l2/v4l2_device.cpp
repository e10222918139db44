#include "hal/v4l2/v4l2_device.h"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <spdlog/spdlog.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>

#include "core/util/clock.h"

namespace uavm::hal {

namespace {

int Xioctl(int fd, unsigned long request, void* arg) {
  int r;
  do {
    r = ioctl(fd, request, arg);
  } while (r == -1 && errno == EINTR);
  return r;
}

uint32_t ToFourcc(PixelFormat f) {
  switch (f) {
    case PixelFormat::kYuyv:
      return V4L2_PIX_FMT_YUYV;
    case PixelFormat::kNv12:
      return V4L2_PIX_FMT_NV12;
    case PixelFormat::kMjpeg:
      return V4L2_PIX_FMT_MJPEG;
    case PixelFormat::kRgb24:
      return V4L2_PIX_FMT_RGB24;
    case PixelFormat::kBgr24:
      return V4L2_PIX_FMT_BGR24;
  }
  return 0;
}

std::string FourccString(uint32_t f) {
  std::string s;
  for (int i = 0; i < 4; ++i) s += static_cast<char>((f >> (8 * i)) & 0xFF);
  return s;
}

std::string Errno(const char* what) {
  return std::string(what) + ": " + std::strerror(errno);
}

std::string CString(const uint8_t* s, size_t n) {
  return std::string(reinterpret_cast<const char*>(s), strnlen(reinterpret_cast<const char*>(s), n));
}

}  // namespace

V4l2Device::~V4l2Device() {
  Close();
}

Status V4l2Device::Open(const CaptureOptions& o, std::string* error) {
  Close();
  const int fd = ::open(o.device.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    *error = Errno(("open " + o.device).c_str());
    return Status::kError;
  }
  fd_ = fd;
  auto fail = [&](const std::string& why) {
    *error = o.device + ": " + why;
    Close();
    return Status::kError;
  };
  v4l2_capability cap{};
  if (Xioctl(fd, VIDIOC_QUERYCAP, &cap) != 0) return fail(Errno("VIDIOC_QUERYCAP (not a V4L2 device?)"));
  const uint32_t caps = (cap.capabilities & V4L2_CAP_DEVICE_CAPS) != 0 ? cap.device_caps : cap.capabilities;
  card_ = CString(cap.card, sizeof(cap.card));
  driver_ = CString(cap.driver, sizeof(cap.driver));
  if ((caps & V4L2_CAP_VIDEO_CAPTURE) == 0) {
    return fail((caps & V4L2_CAP_VIDEO_CAPTURE_MPLANE) != 0
                    ? "multi-planar capture device: not supported (use its libcamera pipeline)"
                    : "not a video capture device");
  }
  if ((caps & V4L2_CAP_STREAMING) == 0) return fail("no streaming I/O (mmap)");

  v4l2_format fmt{};
  fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  fmt.fmt.pix.width = static_cast<uint32_t>(o.width);
  fmt.fmt.pix.height = static_cast<uint32_t>(o.height);
  fmt.fmt.pix.pixelformat = ToFourcc(o.format);
  fmt.fmt.pix.field = V4L2_FIELD_NONE;
  if (Xioctl(fd, VIDIOC_S_FMT, &fmt) != 0) return fail(Errno("VIDIOC_S_FMT"));
  if (fmt.fmt.pix.pixelformat != ToFourcc(o.format))
    return fail(std::string("pixel format ") + ToString(o.format) + " not offered (the driver chose " +
                FourccString(fmt.fmt.pix.pixelformat) + "; --list-cameras shows what it has)");
  if (fmt.fmt.pix.width != static_cast<uint32_t>(o.width) || fmt.fmt.pix.height != static_cast<uint32_t>(o.height))
    return fail("size " + std::to_string(o.width) + "x" + std::to_string(o.height) + " not offered (nearest: " +
                std::to_string(fmt.fmt.pix.width) + "x" + std::to_string(fmt.fmt.pix.height) + ")");
  if (fmt.fmt.pix.field != V4L2_FIELD_NONE && fmt.fmt.pix.field != V4L2_FIELD_ANY)
    return fail("interlaced output (field " + std::to_string(fmt.fmt.pix.field) + ") not supported");
  width_ = o.width;
  height_ = o.height;
  format_ = o.format;
  stride_ = static_cast<int>(fmt.fmt.pix.bytesperline);

  actual_fps_ = 0;
  v4l2_streamparm parm{};
  parm.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (Xioctl(fd, VIDIOC_G_PARM, &parm) == 0) {
    if (o.fps > 0 && (parm.parm.capture.capability & V4L2_CAP_TIMEPERFRAME) != 0) {
      parm.parm.capture.timeperframe.numerator = 1;
      parm.parm.capture.timeperframe.denominator = static_cast<uint32_t>(o.fps);
      if (Xioctl(fd, VIDIOC_S_PARM, &parm) != 0) spdlog::warn("{}: {}", o.device, Errno("VIDIOC_S_PARM"));
    }
    const auto& tpf = parm.parm.capture.timeperframe;
    if (tpf.numerator > 0) actual_fps_ = static_cast<double>(tpf.denominator) / tpf.numerator;
  }

  v4l2_requestbuffers req{};
  req.count = static_cast<uint32_t>(o.buffers);
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  if (Xioctl(fd, VIDIOC_REQBUFS, &req) != 0) return fail(Errno("VIDIOC_REQBUFS"));
  if (req.count < static_cast<uint32_t>(o.queue) + 1)
    return fail("the driver gave " + std::to_string(req.count) + " buffers, the queue needs " +
                std::to_string(o.queue + 1));
  if (req.count != static_cast<uint32_t>(o.buffers))
    spdlog::info("{}: driver allocated {} buffers ({} asked)", o.device, req.count, o.buffers);
  maps_.assign(req.count, Mapping{});
  for (uint32_t i = 0; i < req.count; ++i) {
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    buf.index = i;
    if (Xioctl(fd, VIDIOC_QUERYBUF, &buf) != 0) return fail(Errno("VIDIOC_QUERYBUF"));
    void* addr = mmap(nullptr, buf.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd, buf.m.offset);
    if (addr == MAP_FAILED) return fail(Errno("mmap"));
    maps_[i] = {addr, buf.length};
  }
  for (uint32_t i = 0; i < req.count; ++i) {
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    buf.index = i;
    if (Xioctl(fd, VIDIOC_QBUF, &buf) != 0) return fail(Errno("VIDIOC_QBUF"));
  }
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (Xioctl(fd, VIDIOC_STREAMON, &type) != 0) return fail(Errno("VIDIOC_STREAMON"));
  driver_timestamps_ = true;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++generation_;
    outstanding_ = 0;
  }
  return Status::kOk;
}

V4l2Device::Wait V4l2Device::Dequeue(int timeout_ms, CapturedBuffer* out, std::string* error) {
  pollfd p{fd_, POLLIN, 0};
  const int n = poll(&p, 1, timeout_ms);
  if (n < 0) {
    if (errno == EINTR) return Wait::kTimeout;
    *error = Errno("poll");
    return Wait::kLost;
  }
  if (n == 0) return Wait::kTimeout;
  v4l2_buffer buf{};
  buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  buf.memory = V4L2_MEMORY_MMAP;
  if (Xioctl(fd_, VIDIOC_DQBUF, &buf) != 0) {
    if (errno == EAGAIN) {
      if ((p.revents & (POLLERR | POLLHUP | POLLNVAL)) != 0) {
        *error = "poll reported an error on the device";
        return Wait::kLost;
      }
      return Wait::kTimeout;
    }
    *error = Errno("VIDIOC_DQBUF");
    return Wait::kLost;  // ENODEV/EIO and anything unexpected: reopen
  }
  if (buf.index >= maps_.size()) {
    *error = "VIDIOC_DQBUF returned buffer " + std::to_string(buf.index);
    return Wait::kLost;
  }
  uint64_t generation;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++outstanding_;
    generation = generation_;
  }
  CapturedBuffer handle;
  int64_t ts;
  if ((buf.flags & V4L2_BUF_FLAG_TIMESTAMP_MASK) == V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC) {
    ts = static_cast<int64_t>(buf.timestamp.tv_sec) * 1000000000LL + static_cast<int64_t>(buf.timestamp.tv_usec) * 1000;
  } else {
    if (driver_timestamps_) spdlog::warn("{}: driver timestamps are not monotonic: using the dequeue time", card_);
    driver_timestamps_ = false;
    ts = MonotonicNs();
  }
  RawImage raw;
  raw.data = static_cast<const uint8_t*>(maps_[buf.index].addr);
  raw.bytes = std::min<size_t>(buf.bytesused, maps_[buf.index].length);
  raw.width = width_;
  raw.height = height_;
  raw.stride = stride_;
  raw.format = format_;
  handle = CapturedBuffer(this, buf.index, generation, raw, ts, buf.sequence);
  if ((buf.flags & V4L2_BUF_FLAG_ERROR) != 0) {
    return Wait::kCorrupt;  // `handle` re-queues it
  }
  *out = std::move(handle);
  return Wait::kFrame;
}

void V4l2Device::Return(uint32_t slot, uint64_t generation) noexcept {
  std::lock_guard<std::mutex> lock(mutex_);
  if (fd_ >= 0 && generation == generation_ && slot < maps_.size()) {
    v4l2_buffer buf{};
    buf.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = V4L2_MEMORY_MMAP;
    buf.index = slot;
    // A failure here (device gone) shows up at the next DQBUF/poll as a loss; nothing to do now.
    (void)Xioctl(fd_, VIDIOC_QBUF, &buf);
  }
  --outstanding_;
  returned_.notify_all();
}

void V4l2Device::Close() {
  std::unique_lock<std::mutex> lock(mutex_);
  if (fd_ < 0) return;
  returned_.wait(lock, [&] { return outstanding_ <= 0; });
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  (void)Xioctl(fd_, VIDIOC_STREAMOFF, &type);
  for (auto& m : maps_)
    if (m.addr != nullptr) munmap(m.addr, m.length);
  maps_.clear();
  v4l2_requestbuffers req{};
  req.count = 0;
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  (void)Xioctl(fd_, VIDIOC_REQBUFS, &req);
  ::close(fd_);
  fd_ = -1;
  ++generation_;
}

std::vector<V4l2DeviceInfo> ListV4l2Devices() {
  namespace fs = std::filesystem;
  std::vector<std::pair<int, std::string>> nodes;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/dev", ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("video", 0) != 0 || name.size() == 5) continue;
    const std::string num = name.substr(5);
    if (!std::all_of(num.begin(), num.end(), [](char c) { return c >= '0' && c <= '9'; })) continue;
    nodes.emplace_back(std::stoi(num), e.path().string());
  }
  std::sort(nodes.begin(), nodes.end());
  std::vector<V4l2DeviceInfo> out;
  for (const auto& [n, path] : nodes) {
    V4l2DeviceInfo info;
    info.path = path;
    const int fd = ::open(path.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) {
      info.card = Errno("cannot open");
      out.push_back(info);
      continue;
    }
    v4l2_capability cap{};
    if (Xioctl(fd, VIDIOC_QUERYCAP, &cap) == 0) {
      const uint32_t caps = (cap.capabilities & V4L2_CAP_DEVICE_CAPS) != 0 ? cap.device_caps : cap.capabilities;
      info.card = CString(cap.card, sizeof(cap.card));
      info.driver = CString(cap.driver, sizeof(cap.driver));
      info.bus = CString(cap.bus_info, sizeof(cap.bus_info));
      info.capture = (caps & V4L2_CAP_VIDEO_CAPTURE) != 0 && (caps & V4L2_CAP_STREAMING) != 0;
      for (uint32_t i = 0; info.capture; ++i) {
        v4l2_fmtdesc fd_desc{};
        fd_desc.index = i;
        fd_desc.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        if (Xioctl(fd, VIDIOC_ENUM_FMT, &fd_desc) != 0) break;
        std::string line = FourccString(fd_desc.pixelformat);
        const char* ours = nullptr;  // this project's name for it, when V4l2Source takes it
        for (PixelFormat pf :
             {PixelFormat::kYuyv, PixelFormat::kNv12, PixelFormat::kMjpeg, PixelFormat::kRgb24, PixelFormat::kBgr24})
          if (ToFourcc(pf) == fd_desc.pixelformat) ours = ToString(pf);
        for (uint32_t j = 0; j < 8; ++j) {
          v4l2_frmsizeenum fs{};
          fs.index = j;
          fs.pixel_format = fd_desc.pixelformat;
          if (Xioctl(fd, VIDIOC_ENUM_FRAMESIZES, &fs) != 0) break;
          line.append(" ");
          if (fs.type == V4L2_FRMSIZE_TYPE_DISCRETE) {
            line.append(std::to_string(fs.discrete.width)).append("x").append(std::to_string(fs.discrete.height));
          } else {
            line.append(std::to_string(fs.stepwise.min_width)).append("x");
            line.append(std::to_string(fs.stepwise.min_height)).append("-");
            line.append(std::to_string(fs.stepwise.max_width)).append("x");
            line.append(std::to_string(fs.stepwise.max_height));
            break;
          }
        }
        line.append(ours != nullptr ? std::string("  (format=") + ours + ")" : std::string("  (not supported)"));
        info.formats.push_back(line);
      }
    } else {
      info.card = Errno("VIDIOC_QUERYCAP");
    }
    ::close(fd);
    out.push_back(info);
  }
  return out;
}

}  // namespace uavm::hal
