// A flight controller's MAVLink stream over UDP, made with node-mavlink, for a camera flight (tests/vm/: the camera VM's
// georeferenced flight): HEARTBEAT, GLOBAL_POSITION_INT and ATTITUDE at RATE Hz to 127.0.0.1:PORT. The vehicle hovers
// at (LAT0, LON0) until T0, then flies a straight line at EAST_MPS / NORTH_MPS for SECONDS, then hovers at its end;
// HEIGHT_M above take-off. T0 is when it starts sending: it prints "T0 <unix ms>" once (the test moves the camera's
// picture on the same clock), then the text of every STATUSTEXT the mapper sends back. Stops when its stdin closes.
// Usage: node fly_udp.mjs PORT LAT0 LON0 EAST_MPS NORTH_MPS SECONDS HEIGHT_M RATE
import dgram from 'node:dgram'
import { MavLinkProtocolV2, MavLinkPacketSplitter, MavLinkPacketParser, common, minimal } from 'node-mavlink'
import { Readable } from 'node:stream'

const [port, lat0, lon0, east, north, seconds, height, rate] = process.argv.slice(2).map(Number)
const socket = dgram.createSocket('udp4')
const incoming = new Readable({ read() {} })
incoming.pipe(new MavLinkPacketSplitter()).pipe(new MavLinkPacketParser()).on('data', packet => {
  if (packet.header.msgid === common.StatusText.MSG_ID) {
    console.log(`STATUSTEXT ${packet.protocol.data(packet.payload, common.StatusText).text}`)
  }
})
socket.on('message', data => incoming.push(data))
const protocol = new MavLinkProtocolV2(1, 1)
const metresPerDegLat = 6378137 * Math.PI / 180
const metresPerDegLon = metresPerDegLat * Math.cos(lat0 * Math.PI / 180)
const speed = Math.hypot(east, north)
const course = (Math.atan2(east, north) * 180 / Math.PI + 360) % 360
const t0 = Date.now()
let seq = 0

function send() {
  const ms = Date.now() - t0
  const t = Math.min(Math.max(ms / 1000, 0), seconds)
  const moving = ms / 1000 < seconds
  const hb = new minimal.Heartbeat()
  hb.type = 2; hb.autopilot = 3; hb.baseMode = 209; hb.customMode = 4; hb.systemStatus = 4; hb.mavlinkVersion = 3
  const g = new common.GlobalPositionInt()
  g.timeBootMs = ms + 60000
  g.lat = Math.round((lat0 + north * t / metresPerDegLat) * 1e7)
  g.lon = Math.round((lon0 + east * t / metresPerDegLon) * 1e7)
  g.alt = Math.round((200 + height) * 1000); g.relativeAlt = Math.round(height * 1000)
  g.vx = moving ? Math.round(north * 100) : 0; g.vy = moving ? Math.round(east * 100) : 0; g.vz = 0
  g.hdg = speed > 0 ? Math.round(course * 100) % 36000 : 65535
  const a = new common.Attitude()
  a.timeBootMs = g.timeBootMs; a.roll = 0; a.pitch = 0; a.yaw = course * Math.PI / 180
  const seqByte = seq++ & 0xff
  socket.send(Buffer.concat([hb, g, a].map(m => Buffer.from(protocol.serialize(m, seqByte)))), port, '127.0.0.1')
}

console.log(`T0 ${t0}`)
send()
const timer = setInterval(send, 1000 / rate)
process.stdin.on('data', () => {})
process.stdin.on('end', () => {
  clearInterval(timer)
  setTimeout(() => { socket.close(); process.exit(0) }, 200)
})
process.stdin.resume()
