// Writes a MAVLink telemetry log (.tlog: 8-byte big-endian UNIX microseconds before each packet) with node-mavlink,
// an implementation independent of ours, and the values it encoded (expected.json), for tests/mavlink_test.cpp.
// Usage: node make_mavlink.mjs OUT_DIR [--no-camera]  (without camera trigger messages: frames then match by time)
import { writeFileSync, mkdirSync } from 'node:fs'
import { MavLinkProtocolV1, MavLinkProtocolV2, common, minimal, ardupilotmega } from 'node-mavlink'

const out = process.argv[2]
const withCamera = process.argv[3] !== '--no-camera'
mkdirSync(out, { recursive: true })
const v1 = new MavLinkProtocolV1(1, 1)
const v2 = new MavLinkProtocolV2(1, 1)
const chunks = []
const expected = []
let seq = 0
const t0 = 1700000000000000n  // 2023-11-14, microseconds

function put(protocol, msg, unixUs, fields) {
  const stamp = Buffer.alloc(8)
  stamp.writeBigUInt64BE(unixUs)
  chunks.push(stamp, Buffer.from(protocol.serialize(msg, seq++ & 0xff)))
  if (fields) expected.push({ unix_us: Number(unixUs), version: protocol === v1 ? 1 : 2, ...fields })
}

for (let i = 0; i < 40; ++i) {
  const us = t0 + BigInt(i) * 200000n
  const hb = new minimal.Heartbeat()
  hb.type = 2; hb.autopilot = 3; hb.baseMode = 81; hb.customMode = i; hb.systemStatus = 4; hb.mavlinkVersion = 3
  put(v2, hb, us, { msgid: 0, custom_mode: i, type: 2, autopilot: 3 })

  const st = new common.SystemTime()
  st.timeUnixUsec = us; st.timeBootMs = 60000 + i * 200
  put(v2, st, us, { msgid: 2, time_unix_usec: Number(us), time_boot_ms: 60000 + i * 200 })

  const gp = new common.GlobalPositionInt()
  const lat = 501234567 + i * 91, lon = -1234567 - i * 137
  gp.timeBootMs = 60000 + i * 200; gp.lat = lat; gp.lon = lon; gp.alt = 123456 + i; gp.relativeAlt = 80000 + 10 * i
  gp.vx = 510; gp.vy = -20; gp.vz = 3; gp.hdg = i === 3 ? 65535 : 9000 + i
  put(v2, gp, us, { msgid: 33, time_boot_ms: 60000 + i * 200, lat_deg: lat * 1e-7, lon_deg: lon * 1e-7,
    alt_msl_m: (123456 + i) / 1000, relative_alt_m: (80000 + 10 * i) / 1000, vx_mps: 5.1, vy_mps: -0.2, vz_mps: 0.03,
    heading_deg: i === 3 ? null : (9000 + i) / 100 })

  const at = new common.Attitude()
  at.timeBootMs = 60000 + i * 200; at.roll = 0.015625 * i; at.pitch = -0.03125; at.yaw = 1.5
  put(v2, at, us, { msgid: 30, roll_rad: 0.015625 * i, pitch_rad: -0.03125, yaw_rad: 1.5 })

  const g = new common.GpsRawInt()
  g.timeUsec = us; g.fixType = i === 7 ? 1 : 3; g.lat = lat; g.lon = lon; g.alt = 170000; g.eph = 120; g.epv = 65535
  g.vel = 510; g.cog = 9000; g.satellitesVisible = 14
  const even = i % 2 === 0
  if (!even) { g.hAcc = 1500; g.vAcc = 2500 }
  // MAVLink 1 carries no extensions: even records are v1, odd ones v2 with accuracies.
  put(even ? v1 : v2, g, us, { msgid: 24, lat_deg: lat * 1e-7, lon_deg: lon * 1e-7, alt_msl_m: 170,
    fix_type: i === 7 ? 1 : 3, satellites: 14, eph: 1.2, h_acc_m: even ? null : 1.5, v_acc_m: even ? null : 2.5 })

  const sys = new common.SysStatus()  // a message the mapper does not read: skipped and counted
  sys.voltageBattery = 16000
  put(v2, sys, us, null)

  if (withCamera && i % 5 === 4) {
    const cf = new ardupilotmega.CameraFeedback()
    cf.timeUsec = us; cf.lat = lat; cf.lng = lon; cf.altMsl = 170.5; cf.altRel = 80.25; cf.roll = 1.5; cf.pitch = -2.5
    cf.yaw = 271.25; cf.focLen = 8.8; cf.imgIdx = (i + 1) / 5; cf.targetSystem = 0; cf.camIdx = 0; cf.flags = 0
    put(v2, cf, us, { msgid: 180, lat_deg: lat * 1e-7, lon_deg: lon * 1e-7, alt_msl_m: 170.5, alt_rel_m: 80.25,
      roll_deg: 1.5, pitch_deg: -2.5, yaw_deg: 271.25, image_index: (i + 1) / 5 })

    const ic = new common.CameraImageCaptured()
    ic.timeBootMs = 60000 + i * 200; ic.timeUtc = us; ic.cameraId = 1; ic.lat = lat; ic.lon = lon; ic.alt = 170500
    ic.relativeAlt = 80250; ic.q = [1, 0, 0, 0.5]; ic.imageIndex = (i + 1) / 5; ic.captureResult = 1
    ic.fileUrl = `IMG_${1000 + (i + 1) / 5}.JPG`
    put(v2, ic, us, { msgid: 263, lat_deg: lat * 1e-7, lon_deg: lon * 1e-7, alt_msl_m: 170.5, relative_alt_m: 80.25,
      q: [1, 0, 0, 0.5], image_index: (i + 1) / 5, capture_result: 1, file_url: `IMG_${1000 + (i + 1) / 5}.JPG` })
  }
}
writeFileSync(`${out}/flight.tlog`, Buffer.concat(chunks))
writeFileSync(`${out}/expected.json`, JSON.stringify(expected, null, 1))
console.log(`${out}/flight.tlog: ${chunks.length / 2} packets, ${expected.length} the mapper reads`)
