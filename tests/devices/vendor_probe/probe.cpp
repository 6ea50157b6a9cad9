// walkcap's probe of an Xbus device with Xsens' own host library (xspublic, xscontroller).
//
// It does what Xsens' SDK example (example_mti_receive_data) and its ROS driver
// (xdainterface.cpp) do with a device on a serial port: open the port by name (the library
// reads the identity and the device configuration), pick the device, go to configuration,
// set the outputs, register a callback for live packets, go to measurement, receive, go
// back to configuration and close. It prints one "key value" line per fact and exits 0
// only when the device opened, took the configuration and streamed `samples` packets with
// packet counter, SampleTimeFine and status word and no gap in the packet counter.
//
//     probe PORT BAUD SAMPLES TIMEOUT_S RATE_HZ
//
// Built by tests/test_xspublic_probe.py against a private build of the vendor source;
// this file is walkcap's own, the vendor code stays where XSPUBLIC_DIR points.

#include <xscontroller/xscallback.h>
#include <xscontroller/xscontrol_def.h>
#include <xscontroller/xsdevice_def.h>
#include <xstypes/xsdatapacket.h>
#include <xstypes/xsoutputconfigurationarray.h>
#include <xstypes/xstime.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <string>
#include <vector>

// The library logs through a journaller the application owns; the probe keeps none.
class Journaller;
Journaller* gJournal = 0;

namespace {

struct Counts {
	long packets = 0;
	long without_counter = 0;
	long without_time_fine = 0;
	long without_status = 0;
	long without_orientation = 0;
	long without_acceleration = 0;
	long missing = 0;  // packet counter gaps
	int last_counter = -1;
	long errors = 0;
};

class Receiver : public XsCallback {
public:
	explicit Receiver(bool orientation) : m_orientation(orientation) {}

	Counts snapshot() {
		std::lock_guard<std::mutex> lock(m_mutex);
		return m_counts;
	}

	bool waitFor(long packets, double timeout_s) {
		std::unique_lock<std::mutex> lock(m_mutex);
		return m_cv.wait_for(lock, std::chrono::duration<double>(timeout_s),
			[&] { return m_counts.packets >= packets; });
	}

protected:
	void onLiveDataAvailable(XsDevice*, const XsDataPacket* packet) override {
		std::lock_guard<std::mutex> lock(m_mutex);
		Counts& c = m_counts;
		++c.packets;
		if (packet->containsPacketCounter()) {
			int counter = packet->packetCounter();
			if (c.last_counter >= 0)
				c.missing += ((counter - c.last_counter - 1) & 0xFFFF);
			c.last_counter = counter;
		} else {
			++c.without_counter;
		}
		if (!packet->containsSampleTimeFine()) ++c.without_time_fine;
		if (!packet->containsStatus()) ++c.without_status;
		if (m_orientation && !packet->containsOrientation()) ++c.without_orientation;
		if (!packet->containsCalibratedAcceleration()) ++c.without_acceleration;
		m_cv.notify_all();
	}

	void onError(XsDevice*, XsResultValue error) override {
		std::lock_guard<std::mutex> lock(m_mutex);
		++m_counts.errors;
		std::printf("device_error %d\n", (int) error);
	}

private:
	bool m_orientation;
	std::mutex m_mutex;
	std::condition_variable m_cv;
	Counts m_counts;
};

int fail(XsControl* control, const char* what) {
	std::printf("failed %s: %s\n", what, control->lastResultText().c_str());
	std::fflush(stdout);
	control->destruct();
	return 1;
}

}  // namespace

int main(int argc, char** argv) {
	if (argc != 6) {
		std::fprintf(stderr, "usage: probe PORT BAUD SAMPLES TIMEOUT_S RATE_HZ\n");
		return 2;
	}
	const std::string port = argv[1];
	const int baud = std::atoi(argv[2]);
	const long samples = std::atol(argv[3]);
	const double timeout_s = std::atof(argv[4]);
	const uint16_t rate = (uint16_t) std::atoi(argv[5]);

	XsControl* control = XsControl::construct();
	if (!control->openPort(XsString(port), XsBaud::numericToRate(baud)))
		return fail(control, "openPort");
	std::vector<XsDeviceId> ids = control->mainDeviceIds();
	if (ids.empty())
		return fail(control, "mainDeviceIds");
	XsDevice* device = control->device(ids[0]);
	if (!device)
		return fail(control, "device");
	XsDeviceId id = device->deviceId();
	std::printf("device_id %s\n", id.toString().c_str());
	std::printf("product_code %s\n", device->productCode().c_str());
	std::printf("firmware %s\n", device->firmwareVersion().toString().c_str());
	std::printf("imu %d vru %d ahrs %d mti3x0 %d mtix00 %d mti6x0 %d\n", (int) id.isImu(),
		(int) id.isVru(), (int) id.isAhrs(), (int) id.isMti3X0(), (int) id.isMtiX00(),
		(int) id.isMti6X0());
	std::fflush(stdout);

	const bool orientation = id.isVru() || id.isAhrs();
	Receiver receiver(orientation);
	device->addCallbackHandler(&receiver);

	if (!device->gotoConfig())
		return fail(control, "gotoConfig");
	// As Xsens' example and ROS driver ask: the timestamps and the status word at 0 ("with
	// every packet"), UtcTime too (the ROS driver always asks for it), the data at a rate.
	XsOutputConfigurationArray config;
	config.push_back(XsOutputConfiguration(XDI_PacketCounter, 0));
	config.push_back(XsOutputConfiguration(XDI_SampleTimeFine, 0));
	config.push_back(XsOutputConfiguration(XDI_UtcTime, 0));
	config.push_back(XsOutputConfiguration(XDI_StatusWord, 0));
	if (orientation)
		config.push_back(XsOutputConfiguration(XDI_Quaternion, rate));
	config.push_back(XsOutputConfiguration(XDI_Acceleration, rate));
	config.push_back(XsOutputConfiguration(XDI_RateOfTurn, rate));
	if (!device->setOutputConfiguration(config))
		return fail(control, "setOutputConfiguration");
	XsOutputConfigurationArray granted = device->outputConfiguration();
	for (XsSize i = 0; i < granted.size(); ++i)
		std::printf("output 0x%04X %u\n", (unsigned) granted[i].m_dataIdentifier,
			(unsigned) granted[i].m_frequency);
	std::fflush(stdout);

	if (!device->gotoMeasurement())
		return fail(control, "gotoMeasurement");
	bool enough = receiver.waitFor(samples, timeout_s);
	device->gotoConfig();
	Counts c = receiver.snapshot();
	device->removeCallbackHandler(&receiver);
	control->closePort(XsString(port));
	control->destruct();

	std::printf("packets %ld\n", c.packets);
	std::printf("missing %ld\n", c.missing);
	std::printf("without_counter %ld\n", c.without_counter);
	std::printf("without_time_fine %ld\n", c.without_time_fine);
	std::printf("without_status %ld\n", c.without_status);
	std::printf("without_orientation %ld\n", c.without_orientation);
	std::printf("without_acceleration %ld\n", c.without_acceleration);
	std::printf("errors %ld\n", c.errors);
	bool ok = enough && c.missing == 0 && c.without_counter == 0 && c.without_time_fine == 0 &&
		c.without_status == 0 && c.without_orientation == 0 && c.without_acceleration == 0;
	std::printf("result %s\n", ok ? "ok" : "FAILED");
	return ok ? 0 : 1;
}
