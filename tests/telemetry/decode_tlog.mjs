// Reads a telemetry log (.tlog: 8-byte big-endian UNIX microseconds before each packet) with node-mavlink, an
// implementation independent of ours, and prints what it decoded as JSON, for tests/sim_telemetry_e2e_test.cpp: the
// records, packets node-mavlink refused (bad CRC) or did not know, counts per message id and the values of the
// messages the mapper reads.
// Usage: node decode_tlog.mjs FILE.tlog
import { readFileSync } from 'node:fs'
import { MavLinkPacketSplitter, MavLinkPacketParser, minimal, common, ardupilotmega } from 'node-mavlink'

const log = readFileSync(process.argv[2])
const splitter = new MavLinkPacketSplitter()
const parser = splitter.pipe(new MavLinkPacketParser())
const stamps = []
const out = { records: 0, stamps_in_order: true, counts: {}, heartbeat: [], system_time: [], global_position: [],
  gps_raw: [], attitude: [], camera_feedback: [] }
const packets = []
parser.on('data', packet => packets.push(packet))
const done = new Promise(resolve => parser.on('end', resolve))

// The log's own framing (the stamp, then one packet whose size its header gives); node-mavlink checks and decodes.
for (let at = 0; at + 11 <= log.length;) {
  const stamp = log.readBigUInt64BE(at)
  const stx = log[at + 8]
  const size = stx === 0xfd ? 10 + log[at + 9] + 2 + ((log[at + 10] & 1) ? 13 : 0) : 6 + log[at + 9] + 2
  if (stamps.length > 0 && stamp < stamps[stamps.length - 1]) out.stamps_in_order = false
  stamps.push(stamp)
  splitter.write(log.subarray(at + 8, at + 8 + size))
  at += 8 + size
  ++out.records
}
splitter.end()
await done
out.invalid = splitter.invalidPackages
out.unknown = splitter.unknownPackagesCount
out.first_us = Number(stamps[0])
out.last_us = Number(stamps[stamps.length - 1])

const n = v => typeof v === 'bigint' ? Number(v) : v
packets.forEach((packet, i) => {
  const id = packet.header.msgid
  out.counts[id] = (out.counts[id] || 0) + 1
  const data = cls => packet.protocol.data(packet.payload, cls)
  const unix_us = Number(stamps[i])
  if (id === minimal.Heartbeat.MSG_ID) {
    const m = data(minimal.Heartbeat)
    out.heartbeat.push({ unix_us, type: m.type, autopilot: m.autopilot, mavlink_version: m.mavlinkVersion })
  } else if (id === common.SystemTime.MSG_ID) {
    const m = data(common.SystemTime)
    out.system_time.push({ unix_us, time_unix_usec: n(m.timeUnixUsec), time_boot_ms: m.timeBootMs })
  } else if (id === common.GlobalPositionInt.MSG_ID) {
    const m = data(common.GlobalPositionInt)
    out.global_position.push({ unix_us, time_boot_ms: m.timeBootMs, lat: m.lat, lon: m.lon, alt: m.alt,
      relative_alt: m.relativeAlt, vx: m.vx, vy: m.vy, hdg: m.hdg })
  } else if (id === common.GpsRawInt.MSG_ID) {
    const m = data(common.GpsRawInt)
    out.gps_raw.push({ unix_us, lat: m.lat, lon: m.lon, fix_type: m.fixType, h_acc: m.hAcc })
  } else if (id === common.Attitude.MSG_ID) {
    const m = data(common.Attitude)
    out.attitude.push({ unix_us, roll: m.roll, pitch: m.pitch, yaw: m.yaw })
  } else if (id === ardupilotmega.CameraFeedback.MSG_ID) {
    const m = data(ardupilotmega.CameraFeedback)
    out.camera_feedback.push({ unix_us, time_usec: n(m.timeUsec), lat: m.lat, lng: m.lng, alt_rel: m.altRel,
      yaw: m.yaw, img_idx: m.imgIdx, completed_captures: m.completedCaptures })
  }
})
console.log(JSON.stringify(out))
