// Sends a MAVLink stream over UDP with node-mavlink, as a flight controller (or mavlink-router) sends it to a GCS
// port: HEARTBEAT at 1 Hz, GLOBAL_POSITION_INT and ATTITUDE at RATE Hz for SECONDS, latitude growing by 1e-6 deg per message from
// 50.0, then stops (telemetry lost). Prints the text of every STATUSTEXT the mapper sends back, one per line.
// Usage: node send_udp.mjs PORT SECONDS RATE
import dgram from 'node:dgram'
import { MavLinkProtocolV2, MavLinkPacketSplitter, MavLinkPacketParser, common, minimal } from 'node-mavlink'
import { Readable } from 'node:stream'

const [port, seconds, rate] = process.argv.slice(2).map(Number)
const socket = dgram.createSocket('udp4')
const incoming = new Readable({ read() {} })
incoming.pipe(new MavLinkPacketSplitter()).pipe(new MavLinkPacketParser()).on('data', packet => {
  if (packet.header.msgid === common.StatusText.MSG_ID) {
    const text = packet.protocol.data(packet.payload, common.StatusText).text
    console.log(`STATUSTEXT ${text}`)
  }
})
socket.on('message', data => incoming.push(data))
const protocol = new MavLinkProtocolV2(1, 1)
let seq = 0
const total = Math.round(seconds * rate)
const timer = setInterval(() => {
  if (seq >= total) {
    clearInterval(timer)
    setTimeout(() => socket.close(), 300)  // answers still on their way
    return
  }
  const g = new common.GlobalPositionInt()
  g.timeBootMs = seq * Math.round(1000 / rate); g.lat = 500000000 + 10 * seq; g.lon = 80000000; g.alt = 400000
  g.relativeAlt = 90000; g.hdg = 18000
  const a = new common.Attitude()
  a.timeBootMs = g.timeBootMs; a.roll = 0.01; a.pitch = -0.02; a.yaw = Math.PI / 2
  const parts = [Buffer.from(protocol.serialize(g, seq & 0xff)), Buffer.from(protocol.serialize(a, seq & 0xff))]
  if (seq % rate === 0) {  // an autopilot's HEARTBEAT at 1 Hz (ArduCopter, MAV_AUTOPILOT_ARDUPILOTMEGA): whose link it is
    const hb = new minimal.Heartbeat()
    hb.type = 2; hb.autopilot = 3; hb.baseMode = 209; hb.customMode = 4; hb.systemStatus = 4; hb.mavlinkVersion = 3
    parts.unshift(Buffer.from(protocol.serialize(hb, seq & 0xff)))
  }
  const packet = Buffer.concat(parts)
  socket.send(packet, port, '127.0.0.1')
  ++seq
}, 1000 / rate)
